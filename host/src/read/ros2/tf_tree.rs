//! The camera's pose from a bag's TF tree (`/tf` and `/tf_static`): the
//! transforms from a fixed frame (`--pose-frame`, by default the tree's
//! root, such as `map` or `world`) down to each depth image's
//! `header.frame_id`, composed.
//!
//! A robot publishes its pose as a chain of links (`map -> odom ->
//! base_link -> camera_link -> camera_depth_optical_frame`), the last ones
//! once on `/tf_static`. Each frame has one parent: a link's static pose
//! applies at every time, a dynamic link's pose is taken at the image's
//! stamp by the pose rule ([`crate::read::timed_poses`]). A frame with two
//! parents, a cycle, or a camera frame not connected to the fixed frame is
//! an error naming the frames; an image whose chain has a dynamic link with
//! no sample near its stamp has no pose (the reader skips and counts it).
//!
//! Frame names are compared as tf2 compares them, without a leading `/`:
//! bags of the tf1 era (TUM RGB-D's among them) name `/world` and
//! `/openni_depth_optical_frame`, and a driver of that era may stamp its
//! images `/camera_depth_optical_frame` under a tree that says
//! `camera_depth_optical_frame`.

use crate::read::timed_poses::{pose_at, PoseInterpolation, TimedPose};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::collections::BTreeMap;

/// One transform of a TF message: `child`'s pose in `parent` at `stamp`.
#[derive(Debug, Clone, PartialEq)]
pub struct Link {
    /// The topic it came on.
    pub topic: String,
    /// Whether it came on a static topic (`/tf_static`): valid at all times.
    pub is_static: bool,
    /// `header.frame_id`.
    pub parent: String,
    /// `child_frame_id`.
    pub child: String,
    /// The child's pose in the parent (the stamp is the header's).
    pub pose: TimedPose,
}

/// A frame's parent and its pose there.
#[derive(Debug, Clone)]
struct Edge {
    parent: String,
    /// Where the edge was first seen, for messages.
    topic: String,
    /// One pose for a static link, the samples (ascending) for a dynamic one.
    poses: Vec<TimedPose>,
    is_static: bool,
}

/// The TF tree of a bag: each frame's parent and the poses of that link.
#[derive(Debug, Default)]
pub struct TfTree {
    edges: BTreeMap<String, Edge>,
}

/// The links from a fixed frame down to a camera frame, resolved once.
#[derive(Debug, Clone)]
pub struct Chain {
    /// The fixed frame (the chain's top).
    pub fixed: String,
    /// The camera frame (the chain's bottom).
    pub camera: String,
    /// The edges' child frames, from the fixed frame's child down to the camera.
    children: Vec<String>,
}

/// A frame's name as tf2 compares it: one leading `/` removed.
fn frame_name(name: &str) -> &str {
    name.strip_prefix('/').unwrap_or(name)
}

fn isometry(p: &TimedPose) -> Isometry3<f64> {
    let [x, y, z, w] = p.rotation;
    Isometry3::from_parts(
        Translation3::new(p.translation[0], p.translation[1], p.translation[2]),
        UnitQuaternion::new_normalize(Quaternion::new(w, x, y, z)),
    )
}

impl TfTree {
    /// Builds the tree from `links` in bag order. A frame given two parents
    /// is an error naming both and the stamp of the second.
    pub fn new(links: Vec<Link>) -> Result<TfTree, String> {
        let mut edges: BTreeMap<String, Edge> = BTreeMap::new();
        for mut link in links {
            link.parent = frame_name(&link.parent).to_owned();
            link.child = frame_name(&link.child).to_owned();
            if link.parent == link.child {
                return Err(format!(
                    "{} at t={:.6}: frame `{}` is given as its own parent",
                    link.topic, link.pose.stamp, link.child
                ));
            }
            match edges.get_mut(&link.child) {
                Some(e) if e.parent != link.parent => {
                    return Err(format!(
                        "frame `{}` has two parents: `{}` (on {}) and `{}` ({} at t={:.6}); \
                         a TF tree gives each frame one",
                        link.child, e.parent, e.topic, link.parent, link.topic, link.pose.stamp
                    ))
                }
                Some(e) => {
                    // A static link republished (latched) keeps its one pose;
                    // a link both static and dynamic is taken as dynamic.
                    if !(e.is_static && link.is_static) {
                        if e.is_static {
                            e.poses.clear();
                        }
                        e.is_static = false;
                        e.poses.push(link.pose);
                    } else {
                        e.poses = vec![link.pose];
                    }
                }
                None => {
                    edges.insert(
                        link.child.clone(),
                        Edge {
                            parent: link.parent,
                            topic: link.topic,
                            poses: vec![link.pose],
                            is_static: link.is_static,
                        },
                    );
                }
            }
        }
        for e in edges.values_mut() {
            e.poses.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
        }
        Ok(TfTree { edges })
    }

    /// Whether the tree has no link at all.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Every frame of the tree, for messages.
    pub fn frames(&self) -> Vec<&str> {
        let mut all: Vec<&str> = self
            .edges
            .iter()
            .flat_map(|(c, e)| [c.as_str(), e.parent.as_str()])
            .collect();
        all.sort_unstable();
        all.dedup();
        all
    }

    /// The frames from `frame` up to its root (`frame` first); a cycle is
    /// an error naming its frames.
    fn ancestors(&self, frame: &str) -> Result<Vec<String>, String> {
        let mut up = vec![frame.to_string()];
        let mut at = frame;
        while let Some(e) = self.edges.get(at) {
            if let Some(k) = up.iter().position(|f| *f == e.parent) {
                let mut cycle: Vec<&str> = up[k..].iter().map(String::as_str).collect();
                cycle.push(&e.parent);
                return Err(format!(
                    "the TF tree has a cycle: {} (each link child -> parent)",
                    cycle.join(" -> ")
                ));
            }
            up.push(e.parent.clone());
            at = &e.parent;
        }
        Ok(up)
    }

    /// The chain from `fixed` (the root above `camera` when `None`) down to
    /// `camera`, or an error naming the frames.
    pub fn chain(&self, fixed: Option<&str>, camera: &str) -> Result<Chain, String> {
        let (fixed, camera) = (fixed.map(frame_name), frame_name(camera));
        if camera.is_empty() {
            return Err(
                "the depth images have no frame_id, so the TF tree cannot place them: give \
                 the camera's frame with --camera-frame"
                    .into(),
            );
        }
        let known =
            |f: &str| self.edges.contains_key(f) || self.edges.values().any(|e| e.parent == f);
        if !known(camera) {
            return Err(format!(
                "the camera frame `{camera}` is never connected in the TF tree (its frames: \
                 {}); --camera-frame names the frame to take in place of the depth images' \
                 header.frame_id",
                self.frames().join(", ")
            ));
        }
        if let Some(f) = fixed.filter(|f| !known(f)) {
            return Err(format!(
                "--pose-frame `{f}` is not in the TF tree (its frames: {})",
                self.frames().join(", ")
            ));
        }
        let up = self.ancestors(camera)?;
        let root = up.last().cloned().unwrap_or_default();
        let fixed = fixed.unwrap_or(&root);
        let Some(k) = up.iter().position(|f| f == fixed) else {
            return Err(format!(
                "no TF path from `{fixed}` down to the camera frame `{camera}`: the camera's \
                 chain is {} (root `{root}`)",
                up.join(" -> ")
            ));
        };
        if k == 0 {
            return Err(format!(
                "--pose-frame `{fixed}` is the camera's own frame: give the fixed frame the \
                 camera moves in (its chain: {})",
                up.join(" -> ")
            ));
        }
        let mut children: Vec<String> = up[..k].to_vec();
        children.reverse();
        Ok(Chain {
            fixed: fixed.to_string(),
            camera: camera.to_string(),
            children,
        })
    }

    /// The camera's pose in the chain's fixed frame at `t`, or the link that
    /// has no pose there (`parent -> child`).
    pub fn pose(
        &self,
        chain: &Chain,
        t: f64,
        tolerance: f64,
        rule: PoseInterpolation,
    ) -> Result<TimedPose, String> {
        let mut composed: Option<Isometry3<f64>> = None;
        let mut only: Option<TimedPose> = None;
        for child in &chain.children {
            let Some(e) = self.edges.get(child) else {
                return Err(format!("no link to `{child}`"));
            };
            let p = if e.is_static {
                e.poses[0]
            } else {
                pose_at(&e.poses, t, tolerance, rule)
                    .ok_or_else(|| format!("{} -> {child}", e.parent))?
            };
            composed = Some(match composed {
                None => {
                    only = Some(p);
                    isometry(&p)
                }
                Some(c) => {
                    only = None;
                    c * isometry(&p)
                }
            });
        }
        // One link: its pose as given, bit for bit.
        if let Some(p) = only {
            return Ok(TimedPose { stamp: t, ..p });
        }
        let c = composed.ok_or("an empty TF chain")?;
        let q = c.rotation;
        Ok(TimedPose {
            stamp: t,
            translation: c.translation.vector.into(),
            rotation: [q.i, q.j, q.k, q.w],
        })
    }

    /// The time span over which every dynamic link of `chain` has samples,
    /// `None` when the chain is all static.
    pub fn span(&self, chain: &Chain) -> Option<(f64, f64)> {
        chain
            .children
            .iter()
            .filter_map(|c| self.edges.get(c))
            .filter(|e| !e.is_static)
            .filter_map(|e| Some((e.poses.first()?.stamp, e.poses.last()?.stamp)))
            .reduce(|a, b| (a.0.max(b.0), a.1.min(b.1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn link(parent: &str, child: &str, stamp: f64, x: f64, is_static: bool) -> Link {
        Link {
            topic: if is_static { "/tf_static" } else { "/tf" }.into(),
            is_static,
            parent: parent.into(),
            child: child.into(),
            pose: TimedPose {
                stamp,
                translation: [x, 0.0, 0.0],
                rotation: [0.0, 0.0, 0.0, 1.0],
            },
        }
    }

    #[test]
    fn a_chain_composes_static_and_interpolated_dynamic_links() {
        let tree = TfTree::new(vec![
            link("base", "cam", 0.0, 0.5, true),
            link("map", "odom", 1.0, 10.0, false),
            link("odom", "base", 1.0, 1.0, false),
            link("odom", "base", 2.0, 2.0, false),
            link("map", "odom", 2.0, 10.0, false),
        ])
        .unwrap();
        let chain = tree.chain(None, "cam").unwrap();
        assert_eq!(chain.fixed, "map");
        let p = tree
            .pose(&chain, 1.5, 0.6, PoseInterpolation::Linear)
            .unwrap();
        assert!((p.translation[0] - 12.0).abs() < 1e-12, "{p:?}");
        // From odom: the odom link is left out.
        let from_odom = tree.chain(Some("odom"), "cam").unwrap();
        let p = tree
            .pose(&from_odom, 2.0, 0.0, PoseInterpolation::Linear)
            .unwrap();
        assert!((p.translation[0] - 2.5).abs() < 1e-12);
        // A stamp with no sample near names the link.
        let e = tree
            .pose(&chain, 5.0, 0.1, PoseInterpolation::Linear)
            .unwrap_err();
        assert!(e.contains("-> odom") || e.contains("-> base"), "{e}");
        assert_eq!(tree.span(&chain), Some((1.0, 2.0)));
    }

    #[test]
    fn frames_are_named_with_or_without_a_leading_slash_as_tf2_names_them() {
        // A tf1-era bag: slashes in the tree, none in the image's frame or
        // in --pose-frame, and a link republished without one.
        let tree = TfTree::new(vec![
            link("/world", "/kinect", 1.0, 1.0, false),
            link("/kinect", "/openni_depth_optical_frame", 0.0, 0.5, true),
            link("world", "kinect", 2.0, 2.0, false),
        ])
        .unwrap();
        for (fixed, camera) in [
            (None, "openni_depth_optical_frame"),
            (Some("world"), "/openni_depth_optical_frame"),
            (Some("/world"), "openni_depth_optical_frame"),
        ] {
            let chain = tree.chain(fixed, camera).unwrap();
            assert_eq!(chain.fixed, "world");
            let p = tree
                .pose(&chain, 1.5, 0.5, PoseInterpolation::Linear)
                .unwrap();
            assert!((p.translation[0] - 2.0).abs() < 1e-12, "{p:?}");
        }
        assert_eq!(
            tree.frames(),
            ["kinect", "openni_depth_optical_frame", "world"]
        );
    }

    #[test]
    fn two_parents_a_cycle_and_unconnected_frames_are_named() {
        let e = TfTree::new(vec![
            link("odom", "base", 1.0, 0.0, false),
            link("map", "base", 1.5, 0.0, false),
        ])
        .unwrap_err();
        assert!(
            e.contains("`base` has two parents") && e.contains("`odom`") && e.contains("`map`"),
            "{e}"
        );
        assert!(e.contains("t=1.5"), "{e}");
        let cyclic = TfTree::new(vec![
            link("odom", "base", 1.0, 0.0, false),
            link("base", "odom", 1.0, 0.0, false),
            link("base", "cam", 0.0, 0.0, true),
        ])
        .unwrap();
        let e = cyclic.chain(None, "cam").unwrap_err();
        assert!(
            e.contains("cycle") && e.contains("odom") && e.contains("base"),
            "{e}"
        );
        let tree = TfTree::new(vec![link("map", "base", 1.0, 0.0, false)]).unwrap();
        let e = tree.chain(None, "cam").unwrap_err();
        assert!(e.contains("`cam` is never connected"), "{e}");
        let e = tree.chain(Some("world"), "base").unwrap_err();
        assert!(e.contains("`world` is not in the TF tree"), "{e}");
        let tree = TfTree::new(vec![
            link("map", "base", 1.0, 0.0, false),
            link("world", "cam", 1.0, 0.0, false),
        ])
        .unwrap();
        let e = tree.chain(Some("map"), "cam").unwrap_err();
        assert!(e.contains("no TF path from `map`"), "{e}");
    }
}
