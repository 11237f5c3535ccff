//! ROS 2 recordings (rosbag2 with MCAP or sqlite3 storage): a bag folder
//! (its `metadata.yaml` and `*.mcap` or `*.db3` files, one or split, plain
//! or compressed by rosbag2: [`bag_files`]) or a single `.mcap` or `.db3`
//! file; and ROS 1 bags (a `.bag` file, format 2.0,
//! chunks uncompressed, bz2 or lz4: [`ros1_storage`]), whose messages are
//! the same types by their ROS 1 names (`sensor_msgs/Image`, ...,
//! `tf/tfMessage`) in ROS 1's serialisation ([`ros1_msgs`]) and are read
//! down the same path ([`wire`] picks the decoder).
//!
//! - depth: `sensor_msgs/msg/Image`, `16UC1` (millimetres, depth scale 1000,
//!   or `--depth-scale`) or `32FC1` (metres, converted to `u16` at the depth
//!   scale; NaN, infinities, values <= 0 or beyond the `u16` range mean "no
//!   measurement"); `is_bigendian` and `step` are honoured. Or
//!   `sensor_msgs/msg/CompressedImage` as `image_transport` records it
//!   (compressedDepth PNG or RVL, 16UC1 or 32FC1, or a 16-bit PNG:
//!   [`depth_codec`]). Another encoding is refused, naming topic and time.
//! - intrinsics: the first `sensor_msgs/msg/CameraInfo` (`k`, row-major 3x3;
//!   skew is refused, distortion is ignored with a warning), unless given.
//! - poses: `geometry_msgs/msg/PoseStamped` or `nav_msgs/msg/Odometry` (the
//!   pose of the depth camera's optical frame), or the TF tree of `/tf` and
//!   `/tf_static` composed from `--pose-frame` (default: the tree's root)
//!   down to each depth image's `frame_id` ([`tf_tree`]).
//! - colour (for `--dataset`): an Image topic in `rgb8`, `bgr8`, `rgba8`,
//!   `bgra8` or `mono8`.
//!
//! Each kind's topic is the one given, else the only candidate in the bag
//! (several candidates: an error listing them; a raw depth topic is
//! preferred to a compressed one). Times are the header stamps (the log
//! time when a stamp is zero). Frames are in stamp order; each takes its
//! pose interpolated at its stamp (or the nearest, `--pose-interpolation`:
//! [`crate::read::timed_poses`]) when a pose sample lies within
//! [`Ros2Options::pose_tolerance`], and the colour image nearest in time
//! within it; a frame with no pose is skipped with a counted warning, and a
//! bag where no frame has one is an error naming the topics and times.

pub mod bag;
pub mod bag_files;
pub mod cdr;
pub mod color_codec;
pub mod depth_codec;
mod kept_chunks;
mod lz4_frame;
mod mcap_storage;
pub mod msgs;
mod pose_source;
mod read_ahead;
pub mod ros1_msgs;
#[doc(hidden)]
pub mod ros1_storage;
mod rvl;
mod sqlite_storage;
pub mod tf_tree;
pub mod wire;

use super::timed_poses::{self, TimedPose};
use super::{text, ReadOptions};
use crate::error::ReadError;
use crate::picture::Image;
use crate::sequence::{CameraModel, DepthImage, DepthSource, Format, FrameInfo, Sequence};
use crate::warning::warn;
use bag::{Channel, Location, Message};
use bag_files::BagFiles;
pub use bag_files::{check_metadata, looks_like_bag, looks_like_ros1_bag};
use std::collections::BTreeMap;
use std::path::Path;
use wire::Wire;

/// Depth units per metre of `16UC1` (millimetres), and of the `u16` that
/// `32FC1` metres are converted to.
pub const DEPTH_SCALE: f64 = 1000.0;

/// Default largest time difference, seconds, between a depth frame and its
/// pose (or colour image).
pub const POSE_TOLERANCE: f64 = 0.05;

/// Which topics to read; `Default`: the only candidate of each kind.
#[derive(Debug, Clone, Default)]
pub struct Ros2Options {
    /// The depth topic (an Image, or a CompressedImage of depth).
    pub depth_topic: Option<String>,
    /// The pose topic (PoseStamped, Odometry or a TFMessage topic).
    pub pose_topic: Option<String>,
    /// The CameraInfo topic.
    pub camera_info_topic: Option<String>,
    /// The colour Image topic.
    pub color_topic: Option<String>,
    /// Poses from TF: the fixed frame the camera's pose is in (the root of
    /// the camera's tree when `None`).
    pub pose_frame: Option<String>,
    /// Poses from TF: the camera's frame, replacing the depth images'
    /// `header.frame_id`.
    pub camera_frame: Option<String>,
    /// Seconds; [`POSE_TOLERANCE`] when `None`.
    pub pose_tolerance: Option<f64>,
}

/// One image message's metadata (its pixels stay in the bag).
#[derive(Debug, Clone)]
struct ImageRef {
    stamp: f64,
    width: u32,
    height: u32,
    /// An Image's encoding, or a CompressedImage's format.
    encoding: String,
    /// How the message is serialised, to decode it again.
    wire: Wire,
    /// A CompressedImage: its codec, or why it is not depth; the size is
    /// read from the payload's header when it is depth.
    compressed: Option<Result<depth_codec::DepthCodec, String>>,
    /// `header.frame_id`: the camera frame, for TF.
    frame_id: String,
    at: Location,
}

/// Everything the scan of the bag found, per topic.
#[derive(Default)]
struct Topics {
    /// Topic -> schema name.
    kinds: BTreeMap<String, String>,
    images: BTreeMap<String, Vec<ImageRef>>,
    infos: BTreeMap<String, Vec<msgs::CameraInfo>>,
    poses: BTreeMap<String, Vec<TimedPose>>,
    /// TF topic -> its transforms, in bag order.
    tf: BTreeMap<String, Vec<tf_tree::Link>>,
}

/// The first bytes of an image message the walk reads where its storage
/// reads a message at a time: the header, the size and encoding (or
/// format) and a depth payload's own header, with room for a frame id of a
/// few hundred characters.
const IMAGE_HEAD: usize = 512;

fn secs(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

/// The header stamp, or the log time when the stamp is zero (unset).
fn stamp_or(stamp: f64, log_time: u64) -> f64 {
    if stamp == 0.0 {
        secs(log_time)
    } else {
        stamp
    }
}

impl Topics {
    /// Takes in message `m` of one of `files`.
    fn visit(&mut self, files: &BagFiles, m: Message<'_>) -> Result<(), bag::BagError> {
        let path = &files.named[m.at.file];
        let Channel {
            topic,
            schema,
            encoding,
        } = m.channel;
        self.kinds
            .entry(topic.clone())
            .or_insert_with(|| schema.clone());
        let wanted = [
            msgs::IMAGE,
            msgs::COMPRESSED_IMAGE,
            msgs::CAMERA_INFO,
            msgs::POSE_STAMPED,
            msgs::ODOMETRY,
            msgs::TF_MESSAGE,
        ];
        if !wanted.contains(&schema.as_str()) {
            return Ok(());
        }
        let bad = |reason: String| {
            (
                path.to_path_buf(),
                format!("{topic} at t={:.6}: {reason}", secs(m.log_time)),
            )
        };
        let Some(wire) = Wire::of(encoding) else {
            return Err(bad(format!(
                "message encoding `{encoding}`, expected cdr (ROS 2) or ros1 (ROS 1)"
            )));
        };
        let undecodable = |e: String| bad(format!("{schema} does not decode: {e}"));
        // An image's first bytes ([`IMAGE_HEAD`]) may be all the storage
        // read; when they do not hold what is read here (a long frame id,
        // a payload cut before its size), or do not decode, the whole
        // message is read, so what it says is what the whole one says.
        let cut = m.data.len() < m.len;
        let whole: bag::MessageBytes;
        match schema.as_str() {
            msgs::IMAGE => {
                let img = match wire.image_head(m.data, m.len) {
                    Ok(img) => img,
                    Err(e) if !cut => return Err(undecodable(e)),
                    Err(_) => {
                        whole = files.whole(m.at, wire == Wire::Cdr)?;
                        wire.image(&whole).map_err(undecodable)?
                    }
                };
                self.images
                    .entry(topic.clone())
                    .or_default()
                    .push(ImageRef {
                        stamp: stamp_or(img.header.stamp, m.log_time),
                        width: img.width,
                        height: img.height,
                        encoding: img.encoding,
                        wire,
                        compressed: None,
                        frame_id: img.header.frame_id,
                        at: m.at,
                    });
            }
            msgs::COMPRESSED_IMAGE => {
                // A depth payload's size is read from its first bytes.
                let size_at_hand = |img: &msgs::CompressedImage<'_>| {
                    depth_codec::codec(&img.format)
                        .map_or(true, |c| depth_codec::size(c, img.data).is_ok())
                };
                let img = match wire.compressed_image_head(m.data, m.len) {
                    Ok(img) if !cut || size_at_hand(&img) => img,
                    Err(e) if !cut => return Err(undecodable(e)),
                    _ => {
                        whole = files.whole(m.at, wire == Wire::Cdr)?;
                        wire.compressed_image(&whole).map_err(undecodable)?
                    }
                };
                let codec = depth_codec::codec(&img.format);
                // A depth payload's size is in its first bytes; a damaged
                // one is refused if its topic is the depth topic.
                let (size, codec) = match codec {
                    Ok(c) => match depth_codec::size(c, img.data) {
                        Ok(size) => (size, Ok(c)),
                        Err(e) => ((0, 0), Err(e)),
                    },
                    Err(e) => ((0, 0), Err(e)),
                };
                self.images
                    .entry(topic.clone())
                    .or_default()
                    .push(ImageRef {
                        stamp: stamp_or(img.header.stamp, m.log_time),
                        width: u32::from(size.0),
                        height: u32::from(size.1),
                        encoding: img.format,
                        wire,
                        compressed: Some(codec),
                        frame_id: img.header.frame_id,
                        at: m.at,
                    });
            }
            msgs::CAMERA_INFO => {
                let info = wire.camera_info(m.data).map_err(undecodable)?;
                let list = self.infos.entry(topic.clone()).or_default();
                // The first one and any that differs are enough.
                if list.last().is_none_or(|l| l.k != info.k) {
                    list.push(info);
                }
            }
            msgs::POSE_STAMPED | msgs::ODOMETRY => {
                let (h, pose) = if schema == msgs::ODOMETRY {
                    wire.odometry(m.data)
                } else {
                    wire.pose_stamped(m.data)
                }
                .map_err(undecodable)?;
                self.poses
                    .entry(topic.clone())
                    .or_default()
                    .push(TimedPose {
                        stamp: stamp_or(h.stamp, m.log_time),
                        translation: pose.translation,
                        rotation: pose.rotation,
                    });
            }
            _ => {
                let links = self.tf.entry(topic.clone()).or_default();
                for t in wire.tf_message(m.data).map_err(undecodable)? {
                    links.push(tf_tree::Link {
                        topic: topic.clone(),
                        is_static: topic.ends_with("tf_static"),
                        parent: t.header.frame_id,
                        child: t.child_frame_id,
                        pose: TimedPose {
                            stamp: stamp_or(t.header.stamp, m.log_time),
                            translation: t.pose.translation,
                            rotation: t.pose.rotation,
                        },
                    });
                }
            }
        }
        Ok(())
    }

    /// How much of a channel's messages [`Topics::visit`] needs: an
    /// image's fields ([`IMAGE_HEAD`] bytes, more read when they do not
    /// hold them), all of the other kinds it reads, none of the rest.
    fn heads(channel: &Channel) -> Option<usize> {
        match channel.schema.as_str() {
            msgs::IMAGE | msgs::COMPRESSED_IMAGE => Some(IMAGE_HEAD),
            msgs::CAMERA_INFO | msgs::POSE_STAMPED | msgs::ODOMETRY | msgs::TF_MESSAGE => None,
            _ => Some(0),
        }
    }

    fn of_kind(&self, kinds: &[&str]) -> Vec<&str> {
        self.kinds
            .iter()
            .filter(|(_, k)| kinds.contains(&k.as_str()))
            .map(|(t, _)| t.as_str())
            .collect()
    }

    /// Image topics (raw or compressed) whose first message passes `first`.
    fn image_topics(&self, first: impl Fn(&ImageRef) -> bool) -> Vec<&str> {
        self.images
            .iter()
            .filter(|(_, v)| v.first().is_some_and(&first))
            .map(|(t, _)| t.as_str())
            .collect()
    }

    /// Image topics (raw) whose first message has one of `encodings`.
    fn images_in(&self, encodings: &[&str]) -> Vec<&str> {
        self.image_topics(|i| i.compressed.is_none() && encodings.contains(&i.encoding.as_str()))
    }

    /// CompressedImage topics whose first message's format is a colour JPEG
    /// or PNG.
    fn compressed_color(&self) -> Vec<&str> {
        self.image_topics(|i| i.compressed.is_some() && color_codec::codec(&i.encoding).is_some())
    }

    /// CompressedImage topics whose first message's format names depth.
    fn compressed_depth(&self) -> Vec<&str> {
        self.image_topics(|i| i.compressed.is_some() && depth_codec::is_depth_format(&i.encoding))
    }
}

const DEPTH_ENCODINGS: [&str; 2] = ["16UC1", "32FC1"];
const COLOR_ENCODINGS: [&str; 5] = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8"];

/// Picks the topic of one kind: the given one (checked to be of that kind),
/// else the only candidate.
fn choose(
    dir: &Path,
    what: &str,
    flag: &str,
    given: Option<&str>,
    candidates: &[&str],
    topics: &Topics,
) -> Result<String, ReadError> {
    if let Some(t) = given {
        return match topics.kinds.get(t) {
            None => Err(text::layout(
                dir,
                format!(
                    "{flag} {t}: no such topic; the bag has {}",
                    topics.kinds.keys().cloned().collect::<Vec<_>>().join(", ")
                ),
            )),
            Some(_) if candidates.contains(&t) => Ok(t.to_string()),
            // An Image topic in another encoding is refused for its
            // encoding, not its kind (which is the one asked for).
            Some(_) if topics.images.contains_key(t) => Err(text::layout(
                dir,
                format!(
                    "{flag} {t}: its images are encoded `{}`, which is not a {what}",
                    topics
                        .images
                        .get(t)
                        .and_then(|v| v.first())
                        .map_or("(no message)", |i| i.encoding.as_str())
                ),
            )),
            Some(kind) => Err(text::layout(
                dir,
                format!("{flag} {t}: a {kind} topic is not a {what}"),
            )),
        };
    }
    match candidates {
        [one] => Ok(one.to_string()),
        [] if topics.kinds.is_empty() => Err(text::layout(
            dir,
            format!("no {what} in the bag: it has no topic at all"),
        )),
        [] => Err(text::layout(
            dir,
            format!(
                "no {what} in the bag (topics: {})",
                topics
                    .kinds
                    .iter()
                    .map(|(t, k)| format!("{t} [{k}]"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
        many => Err(text::layout(
            dir,
            format!(
                "several {what}s: {}; choose one with {flag}",
                many.join(", ")
            ),
        )),
    }
}

/// Reads a ROS 2 recording or a ROS 1 bag (`format` says which, for the
/// sequence's record of it).
pub(crate) fn read(path: &Path, opts: &ReadOptions, format: Format) -> Result<Sequence, ReadError> {
    let ros = &opts.ros2;
    if format == Format::Ros1 && !path.is_file() {
        return Err(text::layout(
            path,
            "a ROS 1 bag is one .bag file, not a folder (give the file)",
        ));
    }
    if format == Format::Ros1 && !bag::is_ros1(path).map_err(layout)? {
        // An older bag (`#ROSBAG V1.2`) or another file named `.bag`.
        return Err(text::layout(
            path,
            "not a ROS 1 bag of format 2.0 (it does not start with `#ROSBAG V2.0`; \
             format 1.2 and older are not read)",
        ));
    }
    let tol = ros.pose_tolerance.unwrap_or(POSE_TOLERANCE);
    if !(tol.is_finite() && tol >= 0.0) {
        return Err(text::layout(
            path,
            format!("pose tolerance must be >= 0 seconds, got {tol}"),
        ));
    }
    let files = BagFiles::open(path)?;
    let mut topics = Topics::default();
    for (i, file) in files.named.iter().enumerate() {
        let cut = files.scan(i, &Topics::heads, &mut |m| topics.visit(&files, m))?;
        if cut > 0 {
            warn(format!(
                "{}: the last {cut} bytes are an incomplete record (recording cut short): ignored",
                file.display()
            ));
        }
    }
    let (depth_topic, depth, size) = depth_frames(path, ros, &mut topics)?;
    // Intrinsics: the CameraInfo beside the image topic (a compressed
    // topic is its image topic and the transport's name).
    let image_topic = match depth.first().and_then(|d| d.compressed.as_ref()) {
        Some(_) => depth_topic
            .rsplit_once('/')
            .map_or(depth_topic.as_str(), |(base, _)| base),
        None => depth_topic.as_str(),
    };
    let camera = match opts.intrinsics {
        Some(k) => k,
        None => camera(path, ros, image_topic, &topics, size)?,
    };
    // Poses.
    let mut poses = pose_source::choose_poses(path, ros, &mut topics)?;
    // Colour (optional).
    // Raw colour is preferred; a robot usually records it compressed
    // (JPEG or PNG through image_transport).
    let raw_color = topics.images_in(&COLOR_ENCODINGS);
    let compressed_color = topics.compressed_color();
    let color_candidates: Vec<&str> = raw_color.iter().chain(&compressed_color).copied().collect();
    let only = if raw_color.is_empty() {
        compressed_color.as_slice()
    } else {
        raw_color.as_slice()
    };
    let color_topic = match (&ros.color_topic, only) {
        (Some(t), _) if *t == depth_topic => {
            return Err(text::layout(
                path,
                format!(
                    "--color-topic {t} is the depth topic: give the colour images' topic \
                     (sensor_msgs/msg/Image, rgb8, bgr8, rgba8, bgra8 or mono8, or its JPEG or \
                     PNG CompressedImage), or leave --color-topic out"
                ),
            ))
        }
        (Some(t), _) => Some(choose(
            path,
            "colour topic (sensor_msgs/msg/Image, rgb8, bgr8, rgba8, bgra8 or mono8, or its \
             JPEG or PNG CompressedImage)",
            "--color-topic",
            Some(t),
            &color_candidates,
            &topics,
        )?),
        (None, [one]) => Some(one.to_string()),
        (None, _) => None,
    };
    let mut color = color_topic
        .as_ref()
        .and_then(|t| topics.images.remove(t))
        .unwrap_or_default();
    color.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
    let color_times: Vec<TimedPose> = color
        .iter()
        .map(|c| TimedPose {
            stamp: c.stamp,
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
        })
        .collect();

    let mut frames = Vec::with_capacity(depth.len());
    let mut refs = Vec::with_capacity(depth.len());
    let mut colors = Vec::with_capacity(depth.len());
    let mut skipped: Vec<f64> = Vec::new();
    for img in &depth {
        let found = poses
            .at(&img.frame_id, img.stamp, tol, opts.pose_interpolation)
            .map_err(|reason| {
                text::layout(
                    path,
                    format!("{depth_topic} at t={:.6}: {reason}", img.stamp),
                )
            })?;
        let Some(p) = found else {
            skipped.push(img.stamp);
            continue;
        };
        let rotation = placedb::Pose::from_quaternion(
            p.translation.map(|c| c as f32),
            p.rotation.map(|c| c as f32),
        )
        .map(|_| {
            // A unit quaternion is kept bit for bit (the same poses as the
            // source the bag was made from); others are normalised.
            let n = p.rotation.iter().map(|c| c * c).sum::<f64>().sqrt();
            if (n - 1.0).abs() <= 1e-9 {
                p.rotation
            } else {
                p.rotation.map(|c| c / n)
            }
        })
        .map_err(|reason| {
            text::layout(
                path,
                format!(
                    "{} at t={:.6}: bad pose {:?} {:?}: {}",
                    poses.name(),
                    img.stamp,
                    p.translation,
                    p.rotation,
                    reason
                ),
            )
        })?;
        let index = frames.len();
        frames.push(FrameInfo {
            index,
            timestamp: img.stamp,
            translation: p.translation,
            rotation,
            depth_name: format!("{depth_topic}@{:.6}", img.stamp),
            color_path: None,
        });
        refs.push(img.clone());
        colors.push(timed_poses::nearest(&color_times, img.stamp, tol).map(|c| color[c].clone()));
    }
    if let (Some(first), Some(last)) = (skipped.first(), skipped.last()) {
        let pose_span = match poses.span() {
            Some((a, b)) => format!("poses span t={a:.6}..{b:.6}"),
            None => "no pose at all".into(),
        };
        let outside = match opts.pose_interpolation {
            timed_poses::PoseInterpolation::Linear => {
                ", or outside the poses' span (interpolation does not extrapolate)"
            }
            timed_poses::PoseInterpolation::Nearest => "",
        };
        let msg = format!(
            "{} of {} depth frames on {depth_topic} have no pose from {} within \
             {tol} s{outside} (t={first:.6}..{last:.6}; {pose_span})",
            skipped.len(),
            depth.len(),
            poses.name()
        );
        if frames.is_empty() {
            return Err(text::layout(path, msg));
        }
        warn(format!("{msg}: skipped"));
    }
    let name = if path.is_file() {
        path.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    } else {
        text::dir_name(path)
    };
    Ok(Sequence {
        name,
        root: Some(path.to_path_buf()),
        format,
        camera,
        depth_scale: opts.depth_scale.unwrap_or(DEPTH_SCALE),
        size,
        frames,
        clock: crate::sequence::Clock::Seconds,
        frames_skipped: skipped.len(),
        pose_interpolation: Some(opts.pose_interpolation),
        source: Box::new(BagSource {
            files,
            depth: refs,
            color: colors,
            depth_scale: opts.depth_scale.unwrap_or(DEPTH_SCALE),
            topic: depth_topic,
            kept: bag::Kept::default(),
        }),
    })
}

/// What one pass over a recording's files met: its messages and their
/// bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Walked {
    pub messages: u64,
    pub bytes: u64,
}

/// One pass over the recording at `path` (a ROS 2 bag or a ROS 1 bag):
/// every chunk decompressed once and every message met in file order (of
/// each as much as a reading needs), none decoded. What any reading of the
/// recording pays at least: `placedb bench` prints it beside the reading's
/// own cost.
pub fn walk(path: &Path) -> Result<Walked, ReadError> {
    let mut walked = Walked::default();
    let files = BagFiles::open(path)?;
    for i in 0..files.len() {
        files.scan(i, &Topics::heads, &mut |m| {
            walked.messages += 1;
            walked.bytes += m.data.len() as u64;
            Ok(())
        })?;
    }
    Ok(walked)
}

/// The depth topic, its images in stamp order and their size.
type DepthFrames = (String, Vec<ImageRef>, (u16, u16));

/// Chooses the depth topic (the given one, else the only raw depth Image
/// topic, else the only compressed depth topic) and returns it, its images
/// in stamp order, checked to be depth of one size, and that size.
fn depth_frames(
    path: &Path,
    ros: &Ros2Options,
    topics: &mut Topics,
) -> Result<DepthFrames, ReadError> {
    let raw = topics.images_in(&DEPTH_ENCODINGS);
    let candidates = if raw.is_empty() {
        topics.compressed_depth()
    } else {
        raw
    };
    let any_image = topics.of_kind(&[msgs::IMAGE, msgs::COMPRESSED_IMAGE]);
    let depth_topic = match ros.depth_topic.as_deref() {
        // A given image topic of another encoding gets the encoding error below.
        Some(t) if any_image.contains(&t) => t.to_string(),
        given => choose(
            path,
            "depth topic (sensor_msgs/msg/Image 16UC1 or 32FC1, or a compressed depth \
             CompressedImage)",
            "--depth-topic",
            given,
            &candidates,
            topics,
        )?,
    };
    let mut depth = topics.images.remove(&depth_topic).unwrap_or_default();
    depth.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
    let first = depth
        .first()
        .cloned()
        .ok_or_else(|| text::layout(path, format!("{depth_topic} has no message")))?;
    for img in &depth {
        let at = |reason: String| {
            text::layout(
                path,
                format!("{depth_topic} at t={:.6}: {reason}", img.stamp),
            )
        };
        match &img.compressed {
            None if !DEPTH_ENCODINGS.contains(&img.encoding.as_str()) => {
                return Err(at(format!(
                    "encoding `{}` is not a depth encoding (16UC1 millimetres or 32FC1 metres)",
                    img.encoding
                )))
            }
            Some(Err(reason)) => {
                return Err(at(format!("CompressedImage `{}`: {reason}", img.encoding)))
            }
            _ => {}
        }
        if (img.width, img.height) != (first.width, first.height) {
            return Err(at(format!(
                "{}x{} image, the first one is {}x{}",
                img.width, img.height, first.width, first.height
            )));
        }
    }
    let side = |v: u32| u16::try_from(v).ok().filter(|&s| s > 0);
    match (side(first.width), side(first.height)) {
        (Some(w), Some(h)) => Ok((depth_topic, depth, (w, h))),
        _ => Err(text::layout(
            path,
            format!(
                "{depth_topic}: images are {}x{}, sides must be 1..=65535",
                first.width, first.height
            ),
        )),
    }
}

fn layout((path, reason): bag::BagError) -> ReadError {
    ReadError::Layout { path, reason }
}

/// The pinhole camera from the CameraInfo topic.
fn camera(
    path: &Path,
    ros: &Ros2Options,
    depth_topic: &str,
    topics: &Topics,
    size: (u16, u16),
) -> Result<CameraModel, ReadError> {
    let candidates = topics.of_kind(&[msgs::CAMERA_INFO]);
    // Several cameras: the one beside the depth topic (same namespace).
    let ns = depth_topic.rsplit_once('/').map_or("", |(ns, _)| ns);
    let beside: Vec<&str> = candidates
        .iter()
        .copied()
        .filter(|t| t.rsplit_once('/').is_some_and(|(n, _)| n == ns))
        .collect();
    let pool = if ros.camera_info_topic.is_none() && candidates.len() > 1 && beside.len() == 1 {
        beside
    } else {
        candidates
    };
    let topic = choose(
        path,
        "camera info topic (sensor_msgs/msg/CameraInfo; or give --intrinsics)",
        "--camera-info-topic",
        ros.camera_info_topic.as_deref(),
        &pool,
        topics,
    )?;
    let infos = topics.infos.get(&topic).map(Vec::as_slice).unwrap_or(&[]);
    let Some(info) = infos.first() else {
        return Err(text::layout(path, format!("{topic} has no message")));
    };
    let at = |reason: String| {
        text::layout(
            path,
            format!("{topic} at t={:.6}: {reason}", info.header.stamp),
        )
    };
    if info.width != 0 && (info.width, info.height) != (u32::from(size.0), u32::from(size.1)) {
        return Err(at(format!(
            "camera is {}x{}, the depth images are {}x{}",
            info.width, info.height, size.0, size.1
        )));
    }
    let k = info.k;
    if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(at(format!(
            "k = {k:?} is not [fx 0 cx; 0 fy cy; 0 0 1] (skew is not supported)"
        )));
    }
    let model = CameraModel {
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
    };
    super::check_camera(&model).map_err(at)?;
    if info.d.iter().any(|&d| d != 0.0) {
        warn(format!(
            "{topic}: distortion {:?} is ignored (pinhole model only)",
            info.d
        ));
    }
    if infos.len() > 1 {
        warn(format!(
            "{topic}: the intrinsics change during the recording; the first are used"
        ));
    }
    Ok(model)
}

/// Depth (and colour) of a bag's frames, read back from the bag on demand.
struct BagSource {
    files: BagFiles,
    depth: Vec<ImageRef>,
    color: Vec<Option<ImageRef>>,
    depth_scale: f64,
    topic: String,
    /// What reading the frames keeps between them (chunks decompressed).
    kept: bag::Kept,
}

impl BagSource {
    /// Image `r`'s message read back; a refusal names the topic and time.
    fn message(&self, r: &ImageRef, topic: &str) -> Result<bag::MessageBytes, ReadError> {
        let cdr = r.wire == Wire::Cdr;
        self.files
            .fetch(r.at, cdr, &self.kept)
            .map_err(|e| match e {
                ReadError::Layout { path, reason } => ReadError::Layout {
                    path,
                    reason: format!("{topic} at t={:.6}: {reason}", r.stamp),
                },
                other => other,
            })
    }
}

impl DepthSource for BagSource {
    fn depth(&self, i: usize) -> Result<DepthImage, ReadError> {
        let mut image = DepthImage::default();
        self.depth_into(i, &mut image).map(|()| image)
    }

    fn depth_into(&self, i: usize, image: &mut DepthImage) -> Result<(), ReadError> {
        let r = self.depth.get(i).ok_or_else(|| {
            text::layout(
                &self.files.named[0],
                format!("frame {i} requested, the bag has {}", self.depth.len()),
            )
        })?;
        let bytes = self.message(r, &self.topic)?;
        let at = |reason: String| {
            text::layout(
                &self.files.named[r.at.file],
                format!("{} at t={:.6}: {reason}", self.topic, r.stamp),
            )
        };
        if r.compressed.is_some() {
            let img = r.wire.compressed_image(&bytes).map_err(&at)?;
            let codec = depth_codec::codec(&img.format).map_err(&at)?;
            (image.width, image.height) = (0, 0);
            let (width, height) =
                depth_codec::decode_into(codec, img.data, self.depth_scale, &mut image.data)
                    .map_err(at)?;
            (image.width, image.height) = (width, height);
            return Ok(());
        }
        let img = r.wire.image(&bytes).map_err(&at)?;
        decode_depth_into(&img, self.depth_scale, image).map_err(at)
    }

    fn color(&self, i: usize) -> Result<Option<Image>, ReadError> {
        let Some(Some(r)) = self.color.get(i) else {
            return Ok(None);
        };
        let bytes = self.message(r, "colour image")?;
        let at = |reason: String| {
            text::layout(
                &self.files.named[r.at.file],
                format!("colour image at t={:.6}: {reason}", r.stamp),
            )
        };
        if r.compressed.is_some() {
            let img = r.wire.compressed_image(&bytes).map_err(&at)?;
            let codec = color_codec::codec(&img.format).ok_or_else(|| {
                at(format!(
                    "CompressedImage format `{}` is not a colour JPEG or PNG",
                    img.format
                ))
            })?;
            return color_codec::decode(codec, img.data).map(Some).map_err(at);
        }
        let img = r.wire.image(&bytes).map_err(&at)?;
        decode_color(&img).map(Some).map_err(at)
    }
}

/// Rows of `bpp`-byte pixels of `img`, checked against its step and data.
fn rows<'a>(img: &msgs::Image<'a>, bpp: usize) -> Result<Vec<&'a [u8]>, String> {
    let (w, h, step) = (img.width as usize, img.height as usize, img.step as usize);
    let row = w.checked_mul(bpp).ok_or("image too wide")?;
    if step < row {
        return Err(format!("step {step} < {w} pixels of {bpp} bytes"));
    }
    let need = step
        .checked_mul(h.saturating_sub(1))
        .and_then(|n| n.checked_add(row));
    if h > 0 && need.is_none_or(|n| img.data.len() < n) {
        return Err(format!(
            "{} data bytes for {h} rows of step {step}",
            img.data.len()
        ));
    }
    Ok((0..h)
        .map(|v| &img.data[v * step..v * step + row])
        .collect())
}

fn sides(img: &msgs::Image<'_>) -> Result<(u16, u16), String> {
    match (u16::try_from(img.width), u16::try_from(img.height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => Ok((w, h)),
        _ => Err(format!("image is {}x{}", img.width, img.height)),
    }
}

/// A depth Image as `u16` at `depth_scale` units per metre: `16UC1` as
/// stored, `32FC1` metres scaled (invalid or out-of-range values become 0).
pub fn decode_depth(img: &msgs::Image<'_>, depth_scale: f64) -> Result<DepthImage, String> {
    let mut out = DepthImage::default();
    decode_depth_into(img, depth_scale, &mut out).map(|()| out)
}

/// [`decode_depth`] into `out`, reusing its buffer (on an error `out`
/// holds no image).
pub fn decode_depth_into(
    img: &msgs::Image<'_>,
    depth_scale: f64,
    out: &mut DepthImage,
) -> Result<(), String> {
    out.width = 0;
    out.height = 0;
    out.data.clear();
    let (width, height) = sides(img)?;
    let data = &mut out.data;
    data.reserve(usize::from(width) * usize::from(height));
    // One loop per byte order, so that each is a plain copy or swap.
    match (img.encoding.as_str(), img.is_bigendian) {
        ("16UC1", false) => {
            for row in rows(img, 2)? {
                data.extend(
                    row.chunks_exact(2)
                        .map(|b| u16::from_le_bytes([b[0], b[1]])),
                );
            }
        }
        ("16UC1", true) => {
            for row in rows(img, 2)? {
                data.extend(
                    row.chunks_exact(2)
                        .map(|b| u16::from_be_bytes([b[0], b[1]])),
                );
            }
        }
        ("32FC1", big) => {
            for row in rows(img, 4)? {
                data.extend(row.chunks_exact(4).map(|b| {
                    let b = [b[0], b[1], b[2], b[3]];
                    let m = if big {
                        f32::from_be_bytes(b)
                    } else {
                        f32::from_le_bytes(b)
                    };
                    metres_to_units(m, depth_scale)
                }));
            }
        }
        (other, _) => {
            return Err(format!(
                "encoding `{other}` is not a depth encoding (16UC1 or 32FC1)"
            ))
        }
    }
    out.width = width;
    out.height = height;
    Ok(())
}

/// Metres as `u16` depth units at `depth_scale` per metre, rounded; NaN,
/// infinities, values <= 0 or beyond the `u16` range are 0 (no measurement).
pub(crate) fn metres_to_units(m: f32, depth_scale: f64) -> u16 {
    let v = (f64::from(m) * depth_scale).round();
    if v.is_finite() && v > 0.0 && v <= f64::from(u16::MAX) {
        v as u16
    } else {
        0
    }
}

/// A colour Image as RGB bytes.
pub fn decode_color(img: &msgs::Image<'_>) -> Result<Image, String> {
    let (width, height) = sides(img)?;
    let (bpp, order): (usize, [usize; 3]) = match img.encoding.as_str() {
        "rgb8" => (3, [0, 1, 2]),
        "bgr8" => (3, [2, 1, 0]),
        "rgba8" => (4, [0, 1, 2]),
        "bgra8" => (4, [2, 1, 0]),
        "mono8" => (1, [0, 0, 0]),
        other => return Err(format!("colour encoding `{other}` is not supported")),
    };
    let mut rgb = Vec::with_capacity(3 * usize::from(width) * usize::from(height));
    for row in rows(img, bpp)? {
        for px in row.chunks_exact(bpp) {
            rgb.extend(order.map(|c| px[c]));
        }
    }
    Ok(Image {
        width: width.into(),
        height: height.into(),
        rgb,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An sqlite3 bag file (as rosbag2 lays it out) of `rows`, each a topic
    /// (name, schema) and a serialized message.
    fn sqlite_bag(path: &Path, rows: &[((&str, &str), Vec<u8>)]) {
        let _ = std::fs::remove_file(path);
        let db = rusqlite::Connection::open(path).unwrap();
        db.execute_batch(
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
             timestamp INTEGER NOT NULL, data BLOB NOT NULL);",
        )
        .unwrap();
        let mut topics: Vec<(&str, &str)> = Vec::new();
        for (t, ((name, schema), data)) in rows.iter().enumerate() {
            if !topics.contains(&(name, schema)) {
                topics.push((name, schema));
                db.execute(
                    "INSERT INTO topics VALUES (?1, ?2, ?3, 'cdr', '')",
                    rusqlite::params![topics.len() as i64, name, schema],
                )
                .unwrap();
            }
            let topic = topics.iter().position(|n| *n == (*name, *schema)).unwrap() as i64 + 1;
            db.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (?1, ?2, ?3)",
                rusqlite::params![topic, 1_000 + t as i64, data],
            )
            .unwrap();
        }
    }

    /// What the walk of the bag at `path` found of its images (or its
    /// error), reading of each message what `heads` asks for, and how many
    /// messages it was handed only the head of.
    fn walk_images(path: &Path, heads: bag::Heads<'_>) -> (Result<String, String>, usize) {
        let (mut topics, mut cut) = (Topics::default(), 0);
        let files = BagFiles::open(path).unwrap();
        let walked = files.scan(0, heads, &mut |m| {
            cut += usize::from(m.data.len() < m.len);
            topics.visit(&files, m)
        });
        let found = walked
            .map(|_| format!("{:?}", topics.images))
            .map_err(|e| e.to_string());
        (found, cut)
    }

    #[test]
    fn an_sqlite_walk_of_images_heads_finds_what_whole_messages_say() {
        let path = std::env::temp_dir().join(format!("placedb-heads-{}.db3", std::process::id()));
        let long = "camera_depth_optical_frame/".repeat(30); // beyond IMAGE_HEAD
        let pixels: Vec<u8> = (0..64 * 48 * 2).map(|i| (i * 7) as u8).collect();
        let image = |frame: &str, data: &[u8]| {
            msgs::encode_image(&msgs::Image {
                header: msgs::Header {
                    stamp: 2.5,
                    frame_id: frame.into(),
                },
                height: 48,
                width: 64,
                encoding: "16UC1".into(),
                is_bigendian: false,
                step: 128,
                data,
            })
        };
        // compressedDepth RVL: the ConfigHeader, columns and rows, words.
        let mut rvl = vec![0u8; 12];
        rvl.extend(64u32.to_le_bytes());
        rvl.extend(48u32.to_le_bytes());
        rvl.extend(rvl::tests::encode(&[1000; 64 * 48]));
        let compressed = |frame: &str, data: &[u8]| {
            msgs::encode_compressed_image(&msgs::CompressedImage {
                header: msgs::Header {
                    stamp: 3.5,
                    frame_id: frame.into(),
                },
                format: "16UC1; compressedDepth rvl".into(),
                data,
            })
        };
        let depth = ("/depth", msgs::IMAGE);
        let packed = ("/depth/compressedDepth", msgs::COMPRESSED_IMAGE);
        let cloud = ("/points", "sensor_msgs/msg/PointCloud2");
        let mut rows = vec![
            (depth, image("cam", &pixels)),
            (depth, image(&long, &pixels)),
            (packed, compressed("cam", &rvl)),
            (packed, compressed(&long, &rvl)),
            (cloud, vec![7; 5000]),
        ];
        // Frame ids that put the head's end inside the payload's header.
        for n in (440..=500).step_by(4) {
            rows.push((packed, compressed(&"f".repeat(n), &rvl)));
        }
        sqlite_bag(&path, &rows);
        let (whole, none_cut) = walk_images(&path, &|_| None);
        let (heads, cut) = walk_images(&path, &Topics::heads);
        assert!(whole.as_ref().is_ok_and(|w| w.contains(&long)), "{whole:?}");
        assert_eq!(heads, whole);
        // Every image and the point cloud were handed over as heads.
        assert_eq!((none_cut, cut), (0, rows.len()));
        // The same messages compressed as rosbag2 compresses them
        // (--compression-mode message): heads of them decompressed, or
        // whole ones where a head does not hold the fields, find the same.
        let zstd_rows: Vec<_> = rows
            .iter()
            .map(|(topic, data)| (*topic, zstd::bulk::compress(data, 3).unwrap()))
            .collect();
        sqlite_bag(&path, &zstd_rows);
        assert_eq!(walk_images(&path, &Topics::heads).0, whole);
        assert_eq!(walk_images(&path, &|_| None).0, whole);
        // Damage past the head is found as reading the whole message finds
        // it: a pixel count beyond the message, a payload cut inside its
        // header (behind a long frame id).
        let mut short = image("cam", &pixels);
        short.truncate(short.len() - 1);
        for (topic, bad) in [(depth, short), (packed, compressed(&long, &rvl[..14]))] {
            sqlite_bag(&path, &[(topic, bad.clone())]);
            let (whole, _) = walk_images(&path, &|_| None);
            let (heads, _) = walk_images(&path, &Topics::heads);
            assert_eq!(heads, whole);
            sqlite_bag(&path, &[(topic, zstd::bulk::compress(&bad, 3).unwrap())]);
            assert_eq!(walk_images(&path, &Topics::heads).0, whole);
        }
        std::fs::remove_file(&path).unwrap();
    }

    fn image<'a>(
        encoding: &str,
        w: u32,
        h: u32,
        step: u32,
        big: bool,
        data: &'a [u8],
    ) -> msgs::Image<'a> {
        msgs::Image {
            header: msgs::Header {
                stamp: 1.0,
                frame_id: String::new(),
            },
            height: h,
            width: w,
            encoding: encoding.into(),
            is_bigendian: big,
            step,
            data,
        }
    }

    #[test]
    fn depth_encodings_byte_orders_and_step() {
        // 2x2 16UC1 little-endian with 2 bytes of row padding.
        let le = [0xe8, 0x03, 0x01, 0x00, 9, 9, 0x00, 0x00, 0xff, 0xff, 9, 9];
        let d = decode_depth(&image("16UC1", 2, 2, 6, false, &le), 1000.0).unwrap();
        assert_eq!(d.data, [1000, 1, 0, 65535]);
        let be = [0x03, 0xe8, 0x00, 0x01];
        let d = decode_depth(&image("16UC1", 2, 1, 4, true, &be), 1000.0).unwrap();
        assert_eq!(d.data, [1000, 1]);
        // 32FC1 metres: scaled; NaN, inf, negative, too far are no measurement.
        let m: Vec<u8> = [1.5f32, f32::NAN, f32::INFINITY, -1.0, 70.0, 0.0004]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let d = decode_depth(&image("32FC1", 6, 1, 24, true, &m), 1000.0).unwrap();
        assert_eq!(d.data, [1500, 0, 0, 0, 0, 0]);
        let d = decode_depth(&image("32FC1", 6, 1, 24, true, &m), 5000.0).unwrap();
        assert_eq!(d.data, [7500, 0, 0, 0, 0, 2]);
        // Refusals: encoding, short data, short step, zero size.
        assert!(decode_depth(&image("mono16", 2, 1, 4, false, &be), 1000.0)
            .unwrap_err()
            .contains("mono16"));
        assert!(decode_depth(&image("16UC1", 2, 2, 4, false, &be), 1000.0).is_err());
        assert!(decode_depth(&image("16UC1", 2, 1, 3, false, &be), 1000.0).is_err());
        assert!(decode_depth(&image("16UC1", 0, 1, 0, false, &[]), 1000.0).is_err());
    }

    #[test]
    fn colour_encodings() {
        let bgr = [1, 2, 3, 4, 5, 6];
        let c = decode_color(&image("bgr8", 2, 1, 6, false, &bgr)).unwrap();
        assert_eq!(c.rgb, [3, 2, 1, 6, 5, 4]);
        let c = decode_color(&image("mono8", 2, 1, 2, false, &[7, 8])).unwrap();
        assert_eq!(c.rgb, [7, 7, 7, 8, 8, 8]);
        assert!(decode_color(&image("yuv422", 2, 1, 4, false, &[0; 4])).is_err());
    }
}
