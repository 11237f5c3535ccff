//! The ROS 2 messages the bag reader needs, decoded from CDR ([`super::cdr`])
//! field by field as their `.msg` definitions lay them out, and encoded the
//! same way (for tests, fuzz checks and tools that write bags).
//!
//! | type | fields read |
//! |---|---|
//! | `sensor_msgs/msg/Image` | header, height, width, encoding, is_bigendian, step, data |
//! | `sensor_msgs/msg/CompressedImage` | header, format, data |
//! | `sensor_msgs/msg/CameraInfo` | header, height, width, d, k |
//! | `geometry_msgs/msg/PoseStamped` | header, pose |
//! | `nav_msgs/msg/Odometry` | header, child_frame_id, pose.pose |
//! | `tf2_msgs/msg/TFMessage` | every transform: header, child_frame_id, transform |

use super::cdr::{CdrError, Reader, Writer};

/// `sensor_msgs/msg/Image`.
pub const IMAGE: &str = "sensor_msgs/msg/Image";
/// `sensor_msgs/msg/CompressedImage` (depth through image_transport).
pub const COMPRESSED_IMAGE: &str = "sensor_msgs/msg/CompressedImage";
/// `sensor_msgs/msg/CameraInfo`.
pub const CAMERA_INFO: &str = "sensor_msgs/msg/CameraInfo";
/// `geometry_msgs/msg/PoseStamped`.
pub const POSE_STAMPED: &str = "geometry_msgs/msg/PoseStamped";
/// `nav_msgs/msg/Odometry`.
pub const ODOMETRY: &str = "nav_msgs/msg/Odometry";
/// `tf2_msgs/msg/TFMessage` (`/tf`, `/tf_static`).
pub const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// `stamp` in seconds.
    pub stamp: f64,
    /// `frame_id`.
    pub frame_id: String,
}

/// A pose or transform: translation and unit quaternion `[x, y, z, w]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseMsg {
    /// Metres.
    pub translation: [f64; 3],
    /// `[x, y, z, w]`, as in the message.
    pub rotation: [f64; 4],
}

/// `sensor_msgs/msg/Image`; `data` borrowed from the message.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<'a> {
    /// The header.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// `16UC1`, `32FC1`, `rgb8`, ...
    pub encoding: String,
    /// Byte order of multi-byte pixels.
    pub is_bigendian: bool,
    /// Bytes per row.
    pub step: u32,
    /// `step * height` bytes.
    pub data: &'a [u8],
}

/// `sensor_msgs/msg/CompressedImage`; `data` borrowed from the message.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage<'a> {
    /// The header.
    pub header: Header,
    /// How `data` is coded: `"16UC1; compressedDepth png"`, `"png"`, ...
    pub format: String,
    /// The coded image.
    pub data: &'a [u8],
}

/// `sensor_msgs/msg/CameraInfo` (the fields a pinhole model needs).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// The header.
    pub header: Header,
    /// Image rows (0 when unset).
    pub height: u32,
    /// Image columns (0 when unset).
    pub width: u32,
    /// Distortion coefficients.
    pub d: Vec<f64>,
    /// Row-major 3x3 intrinsic matrix.
    pub k: [f64; 9],
}

/// One `geometry_msgs/msg/TransformStamped` of a TF message.
#[derive(Debug, Clone, PartialEq)]
pub struct Transform {
    /// Header (`frame_id` is the parent frame).
    pub header: Header,
    /// The child frame.
    pub child_frame_id: String,
    /// Pose of the child in the parent.
    pub pose: PoseMsg,
}

fn header(r: &mut Reader<'_>) -> Result<Header, CdrError> {
    let sec = r.i32()?;
    let nanosec = r.u32()?;
    Ok(Header {
        stamp: f64::from(sec) + f64::from(nanosec) * 1e-9,
        frame_id: r.string()?,
    })
}

fn pose(r: &mut Reader<'_>) -> Result<PoseMsg, CdrError> {
    Ok(PoseMsg {
        translation: r.f64s::<3>()?,
        rotation: r.f64s::<4>()?,
    })
}

/// Decodes an Image.
pub fn image(bytes: &[u8]) -> Result<Image<'_>, CdrError> {
    image_head(bytes, bytes.len())
}

/// Decodes an Image from the first bytes of its `len`: `data` is the part
/// of the pixels they hold ([`Reader::head`]).
pub fn image_head(bytes: &[u8], len: usize) -> Result<Image<'_>, CdrError> {
    let mut r = Reader::head(bytes, len)?;
    Ok(Image {
        header: header(&mut r)?,
        height: r.u32()?,
        width: r.u32()?,
        encoding: r.string()?,
        is_bigendian: r.u8()? != 0,
        step: r.u32()?,
        data: r.bytes()?,
    })
}

/// Decodes a CompressedImage.
pub fn compressed_image(bytes: &[u8]) -> Result<CompressedImage<'_>, CdrError> {
    compressed_image_head(bytes, bytes.len())
}

/// Decodes a CompressedImage from the first bytes of its `len`: `data` is
/// the part of the coded image they hold ([`Reader::head`]).
pub fn compressed_image_head(bytes: &[u8], len: usize) -> Result<CompressedImage<'_>, CdrError> {
    let mut r = Reader::head(bytes, len)?;
    Ok(CompressedImage {
        header: header(&mut r)?,
        format: r.string()?,
        data: r.bytes()?,
    })
}

/// Decodes a CameraInfo (up to `k`).
pub fn camera_info(bytes: &[u8]) -> Result<CameraInfo, CdrError> {
    let mut r = Reader::new(bytes)?;
    let header = header(&mut r)?;
    let height = r.u32()?;
    let width = r.u32()?;
    let _distortion_model = r.string()?;
    Ok(CameraInfo {
        header,
        height,
        width,
        d: r.f64_seq()?,
        k: r.f64s::<9>()?,
    })
}

/// Decodes a PoseStamped.
pub fn pose_stamped(bytes: &[u8]) -> Result<(Header, PoseMsg), CdrError> {
    let mut r = Reader::new(bytes)?;
    Ok((header(&mut r)?, pose(&mut r)?))
}

/// Decodes an Odometry's header and pose (its covariance and twist are not read).
pub fn odometry(bytes: &[u8]) -> Result<(Header, PoseMsg), CdrError> {
    let mut r = Reader::new(bytes)?;
    let h = header(&mut r)?;
    let _child = r.string()?;
    Ok((h, pose(&mut r)?))
}

/// Decodes a TFMessage.
pub fn tf_message(bytes: &[u8]) -> Result<Vec<Transform>, CdrError> {
    let mut r = Reader::new(bytes)?;
    // A TransformStamped is at least 8 + 4 + 4 + 56 bytes.
    let n = r.count(72)?;
    (0..n)
        .map(|_| {
            Ok(Transform {
                header: header(&mut r)?,
                child_frame_id: r.string()?,
                pose: pose(&mut r)?,
            })
        })
        .collect()
}

fn put_header(w: &mut Writer, h: &Header) {
    let sec = h.stamp.floor();
    let nanosec = ((h.stamp - sec) * 1e9).round().min(999_999_999.0);
    w.i32(sec as i32).u32(nanosec as u32).string(&h.frame_id);
}

fn put_pose(w: &mut Writer, p: &PoseMsg) {
    w.f64s(&p.translation).f64s(&p.rotation);
}

/// Encodes an Image (little-endian CDR, as ROS 2 on x86 and ARM writes it).
pub fn encode_image(m: &Image<'_>) -> Vec<u8> {
    let mut w = Writer::new(true);
    put_header(&mut w, &m.header);
    w.u32(m.height)
        .u32(m.width)
        .string(&m.encoding)
        .u8(u8::from(m.is_bigendian))
        .u32(m.step)
        .bytes(m.data);
    w.finish()
}

/// Encodes a CompressedImage.
pub fn encode_compressed_image(m: &CompressedImage<'_>) -> Vec<u8> {
    let mut w = Writer::new(true);
    put_header(&mut w, &m.header);
    w.string(&m.format).bytes(m.data);
    w.finish()
}

/// Encodes a CameraInfo (plumb_bob; `r` identity, `p` from `k`, no binning, no ROI).
pub fn encode_camera_info(m: &CameraInfo) -> Vec<u8> {
    let mut w = Writer::new(true);
    put_header(&mut w, &m.header);
    let k = &m.k;
    let p = [
        k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0,
    ];
    w.u32(m.height)
        .u32(m.width)
        .string("plumb_bob")
        .f64_seq(&m.d)
        .f64s(k)
        .f64s(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
        .f64s(&p)
        .u32(0)
        .u32(0);
    // RegionOfInterest: x_offset, y_offset, height, width, do_rectify.
    w.u32(0).u32(0).u32(0).u32(0).u8(0);
    w.finish()
}

/// Encodes a PoseStamped.
pub fn encode_pose_stamped(h: &Header, p: &PoseMsg) -> Vec<u8> {
    let mut w = Writer::new(true);
    put_header(&mut w, h);
    put_pose(&mut w, p);
    w.finish()
}

/// Encodes an Odometry with zero covariance and twist.
pub fn encode_odometry(h: &Header, child: &str, p: &PoseMsg) -> Vec<u8> {
    let mut w = Writer::new(true);
    put_header(&mut w, h);
    w.string(child);
    put_pose(&mut w, p);
    w.f64s(&[0.0; 36]).f64s(&[0.0; 6]).f64s(&[0.0; 36]);
    w.finish()
}

/// Encodes a TFMessage.
pub fn encode_tf_message(transforms: &[Transform]) -> Vec<u8> {
    let mut w = Writer::new(true);
    w.u32(transforms.len() as u32);
    for t in transforms {
        put_header(&mut w, &t.header);
        w.string(&t.child_frame_id);
        put_pose(&mut w, &t.pose);
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn h(stamp: f64, frame: &str) -> Header {
        Header {
            stamp,
            frame_id: frame.into(),
        }
    }

    const P: PoseMsg = PoseMsg {
        translation: [1.0, -2.0, 3.5],
        rotation: [0.0, 0.0, 0.6, 0.8],
    };

    #[test]
    fn messages_round_trip() {
        let data = [1u8, 2, 3, 4, 5, 6];
        let img = Image {
            header: h(12.25, "cam"),
            height: 1,
            width: 3,
            encoding: "16UC1".into(),
            is_bigendian: false,
            step: 6,
            data: &data,
        };
        let bytes = encode_image(&img);
        assert_eq!(image(&bytes).unwrap(), img);
        let c = CompressedImage {
            header: h(1.5, "cam"),
            format: "16UC1; compressedDepth png".into(),
            data: &data,
        };
        assert_eq!(compressed_image(&encode_compressed_image(&c)).unwrap(), c);
        let info = CameraInfo {
            header: h(1.0, "cam"),
            height: 480,
            width: 640,
            d: vec![0.0; 5],
            k: [585.0, 0.0, 320.0, 0.0, 585.0, 240.0, 0.0, 0.0, 1.0],
        };
        assert_eq!(camera_info(&encode_camera_info(&info)).unwrap(), info);
        assert_eq!(
            pose_stamped(&encode_pose_stamped(&h(2.5, "map"), &P)).unwrap(),
            (h(2.5, "map"), P)
        );
        assert_eq!(
            odometry(&encode_odometry(&h(3.0, "odom"), "base", &P)).unwrap(),
            (h(3.0, "odom"), P)
        );
        let tf = vec![
            Transform {
                header: h(4.0, "map"),
                child_frame_id: "camera_optical".into(),
                pose: P,
            },
            Transform {
                header: h(4.0, "map"),
                child_frame_id: "base".into(),
                pose: P,
            },
        ];
        assert_eq!(tf_message(&encode_tf_message(&tf)).unwrap(), tf);
    }

    #[test]
    fn a_known_ros2_image_decodes() {
        // A 2x1 16UC1 image as rclpy serializes it (stamp 5 s 6 ns, frame "f").
        let bytes: Vec<u8> = [
            &[0u8, 1, 0, 0][..],
            &5i32.to_le_bytes(),
            &6u32.to_le_bytes(),
            &2u32.to_le_bytes(),
            b"f\0",
            &[0, 0], // pad to 4
            &1u32.to_le_bytes(),
            &2u32.to_le_bytes(),
            &6u32.to_le_bytes(),
            b"16UC1\0",
            &[1], // is_bigendian
            &[0], // pad to 4
            &4u32.to_le_bytes(),
            &4u32.to_le_bytes(),
            &[0x03, 0xe8, 0x00, 0x01],
        ]
        .concat();
        let img = image(&bytes).unwrap();
        assert_eq!(img.header.stamp, 5.0 + 6e-9);
        assert_eq!((img.width, img.height, img.step), (2, 1, 4));
        assert_eq!(img.encoding, "16UC1");
        assert!(img.is_bigendian);
        assert_eq!(img.data, [0x03, 0xe8, 0x00, 0x01]);
        // Cut anywhere: an error, never a panic.
        for n in 0..bytes.len() {
            assert!(image(&bytes[..n]).is_err(), "cut at {n}");
        }
    }
}
