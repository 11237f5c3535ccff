//! Where a bag's depth frames take their poses: a PoseStamped or Odometry
//! topic, or the TF tree ([`super::tf_tree`]), chosen from what the bag holds
//! and the options, and the pose at each frame's stamp by the pose rule.

use super::tf_tree::{Chain, Link, TfTree};
use super::{choose, msgs, Ros2Options, Topics};
use crate::error::ReadError;
use crate::read::text;
use crate::read::timed_poses::{pose_at, PoseInterpolation, TimedPose};
use std::collections::BTreeMap;
use std::path::Path;

/// The poses of a bag.
pub(super) enum PoseSource {
    /// A PoseStamped or Odometry topic's samples, ascending.
    Track {
        topic: String,
        samples: Vec<TimedPose>,
    },
    /// The TF tree, from the fixed frame down to each image's frame.
    Tf {
        tree: TfTree,
        /// `--pose-frame`; the root above the camera when `None`.
        fixed: Option<String>,
        /// `--camera-frame`, replacing the images' `frame_id`.
        camera_frame: Option<String>,
        /// The chain of each camera frame met so far.
        chains: BTreeMap<String, Chain>,
    },
}

impl PoseSource {
    /// What the poses come from, for messages (`/camera/pose`, `TF map ->
    /// camera_depth_optical_frame`).
    pub(super) fn name(&self) -> String {
        match self {
            PoseSource::Track { topic, .. } => topic.clone(),
            PoseSource::Tf {
                chains,
                fixed,
                camera_frame,
                ..
            } => match chains.values().next() {
                Some(c) => format!("TF {} -> {}", c.fixed, c.camera),
                None => format!(
                    "TF {} -> {}",
                    fixed.as_deref().unwrap_or("(root)"),
                    camera_frame.as_deref().unwrap_or("(the images' frame)")
                ),
            },
        }
    }

    /// The time span the poses cover, for messages.
    pub(super) fn span(&self) -> Option<(f64, f64)> {
        match self {
            PoseSource::Track { samples, .. } => {
                Some((samples.first()?.stamp, samples.last()?.stamp))
            }
            PoseSource::Tf { tree, chains, .. } => tree.span(chains.values().next()?),
        }
    }

    /// The pose of an image of frame `frame_id` at `t`: `Ok(None)` when the
    /// samples do not reach `t` (the frame is skipped and counted), an error
    /// when the TF tree cannot place the frame at all.
    pub(super) fn at(
        &mut self,
        frame_id: &str,
        t: f64,
        tolerance: f64,
        rule: PoseInterpolation,
    ) -> Result<Option<TimedPose>, String> {
        match self {
            PoseSource::Track { samples, .. } => Ok(pose_at(samples, t, tolerance, rule)),
            PoseSource::Tf {
                tree,
                fixed,
                camera_frame,
                chains,
            } => {
                let camera = camera_frame.as_deref().unwrap_or(frame_id);
                if !chains.contains_key(camera) {
                    let chain = tree.chain(fixed.as_deref(), camera)?;
                    chains.insert(camera.to_string(), chain);
                }
                let chain = &chains[camera];
                Ok(tree.pose(chain, t, tolerance, rule).ok())
            }
        }
    }
}

/// Whether a TF topic carries static transforms (`/tf_static`, valid at
/// every time).
fn is_static_topic(topic: &str) -> bool {
    topic.ends_with("tf_static")
}

/// Chooses the bag's pose source: the TF tree when `--pose-topic` names a
/// TF topic, `--pose-frame` is given, or the bag has TF but no PoseStamped
/// or Odometry topic; else the PoseStamped or Odometry topic.
pub(super) fn choose_poses(
    path: &Path,
    ros: &Ros2Options,
    topics: &mut Topics,
) -> Result<PoseSource, ReadError> {
    let tf_topics: Vec<String> = topics
        .of_kind(&[msgs::TF_MESSAGE])
        .into_iter()
        .map(String::from)
        .collect();
    let given_tf = ros
        .pose_topic
        .as_deref()
        .filter(|t| tf_topics.iter().any(|f| f == t));
    let candidates = topics.of_kind(&[msgs::POSE_STAMPED, msgs::ODOMETRY]);
    let use_tf = given_tf.is_some()
        || ros.pose_frame.is_some()
        || (ros.pose_topic.is_none() && candidates.is_empty() && !tf_topics.is_empty());
    if !use_tf {
        let topic = choose(
            path,
            "pose topic (geometry_msgs/msg/PoseStamped or nav_msgs/msg/Odometry; or TF)",
            "--pose-topic",
            ros.pose_topic.as_deref(),
            &candidates,
            topics,
        )?;
        let mut samples = topics.poses.remove(&topic).unwrap_or_default();
        samples.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
        return Ok(PoseSource::Track { topic, samples });
    }
    // The given TF topic and every static one, else every TF topic.
    let from: Vec<&String> = tf_topics
        .iter()
        .filter(|t| given_tf.is_none_or(|g| g == t.as_str()) || is_static_topic(t))
        .collect();
    let mut links: Vec<Link> = Vec::new();
    for t in &from {
        links.extend(topics.tf.remove(t.as_str()).unwrap_or_default());
    }
    if links.is_empty() {
        return Err(text::layout(
            path,
            format!(
                "no TF transform in the bag ({}) for --pose-frame: give a pose topic with \
                 --pose-topic",
                if tf_topics.is_empty() {
                    "it has no /tf".to_string()
                } else {
                    format!("TF topics {} are empty", tf_topics.join(", "))
                }
            ),
        ));
    }
    let tree = TfTree::new(links).map_err(|reason| text::layout(path, reason))?;
    Ok(PoseSource::Tf {
        tree,
        fixed: ros.pose_frame.clone(),
        camera_frame: ros.camera_frame.clone(),
        chains: BTreeMap::new(),
    })
}
