//! How a bag's messages are serialised — CDR (ROS 2, [`super::msgs`]) or
//! ROS 1's own ([`super::ros1_msgs`]) — and the one place that picks the
//! decoder, so the reader above takes both down the same path. A decoder's
//! error is a reason in words; the caller names file, topic and time.

use super::{msgs, ros1_msgs};

/// Why a ROS 1 message's first bytes are not decoded: its storage always
/// hands over whole messages, so none is ever asked for.
const PART_OF_ROS1: &str = "only a whole ROS 1 message is decoded";

/// A message encoding the reader decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    /// `cdr`: ROS 2.
    Cdr,
    /// `ros1`: a ROS 1 bag.
    Ros1,
}

impl Wire {
    /// The wire of a channel's message encoding, if it is one read.
    pub fn of(encoding: &str) -> Option<Wire> {
        match encoding {
            "cdr" => Some(Wire::Cdr),
            "ros1" => Some(Wire::Ros1),
            _ => None,
        }
    }

    /// Decodes an Image.
    pub fn image(self, bytes: &[u8]) -> Result<msgs::Image<'_>, String> {
        match self {
            Wire::Cdr => msgs::image(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::image(bytes).map_err(|e| e.to_string()),
        }
    }

    /// Decodes a CompressedImage.
    pub fn compressed_image(self, bytes: &[u8]) -> Result<msgs::CompressedImage<'_>, String> {
        match self {
            Wire::Cdr => msgs::compressed_image(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::compressed_image(bytes).map_err(|e| e.to_string()),
        }
    }

    /// Decodes an Image from the first bytes of its `len` (`data` the part
    /// at hand); a ROS 1 message only whole.
    pub fn image_head(self, bytes: &[u8], len: usize) -> Result<msgs::Image<'_>, String> {
        match self {
            Wire::Cdr => msgs::image_head(bytes, len).map_err(|e| e.to_string()),
            Wire::Ros1 if bytes.len() == len => self.image(bytes),
            Wire::Ros1 => Err(PART_OF_ROS1.into()),
        }
    }

    /// Decodes a CompressedImage from the first bytes of its `len` (`data`
    /// the part at hand); a ROS 1 message only whole.
    pub fn compressed_image_head(
        self,
        bytes: &[u8],
        len: usize,
    ) -> Result<msgs::CompressedImage<'_>, String> {
        match self {
            Wire::Cdr => msgs::compressed_image_head(bytes, len).map_err(|e| e.to_string()),
            Wire::Ros1 if bytes.len() == len => self.compressed_image(bytes),
            Wire::Ros1 => Err(PART_OF_ROS1.into()),
        }
    }

    /// Decodes a CameraInfo.
    pub fn camera_info(self, bytes: &[u8]) -> Result<msgs::CameraInfo, String> {
        match self {
            Wire::Cdr => msgs::camera_info(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::camera_info(bytes).map_err(|e| e.to_string()),
        }
    }

    /// Decodes a PoseStamped's header and pose.
    pub fn pose_stamped(self, bytes: &[u8]) -> Result<(msgs::Header, msgs::PoseMsg), String> {
        match self {
            Wire::Cdr => msgs::pose_stamped(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::pose_stamped(bytes).map_err(|e| e.to_string()),
        }
    }

    /// Decodes an Odometry's header and pose.
    pub fn odometry(self, bytes: &[u8]) -> Result<(msgs::Header, msgs::PoseMsg), String> {
        match self {
            Wire::Cdr => msgs::odometry(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::odometry(bytes).map_err(|e| e.to_string()),
        }
    }

    /// Decodes a TFMessage.
    pub fn tf_message(self, bytes: &[u8]) -> Result<Vec<msgs::Transform>, String> {
        match self {
            Wire::Cdr => msgs::tf_message(bytes).map_err(|e| e.to_string()),
            Wire::Ros1 => ros1_msgs::tf_message(bytes).map_err(|e| e.to_string()),
        }
    }
}
