//! The ROS 1 messages the bag reader needs, decoded from ROS 1's own
//! serialisation into the same structs as the ROS 2 ones ([`super::msgs`]),
//! so the reader treats both alike. ROS 1 lays fields out little-endian with
//! no alignment and no encapsulation header; a string is a `u32` length and
//! its bytes (no NUL), a variable array a `u32` count and its elements, a
//! fixed array its elements; `std_msgs/Header` is `uint32 seq`, `time stamp`
//! (`u32` seconds, `u32` nanoseconds) and `string frame_id`.
//!
//! | type | fields read |
//! |---|---|
//! | `sensor_msgs/Image` | header, height, width, encoding, is_bigendian, step, data |
//! | `sensor_msgs/CompressedImage` | header, format, data |
//! | `sensor_msgs/CameraInfo` | header, height, width, D, K |
//! | `geometry_msgs/PoseStamped` | header, pose |
//! | `nav_msgs/Odometry` | header, child_frame_id, pose.pose |
//! | `tf/tfMessage`, `tf2_msgs/TFMessage` | every transform: header, child_frame_id, transform |
//!
//! Also an encoder of the same messages, for tests and fuzz seeds.

use super::msgs::{CameraInfo, CompressedImage, Header, Image, PoseMsg, Transform};
use std::fmt;

/// Why a ROS 1 message does not decode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DecodeError(pub String);

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

/// A cursor over one ROS 1 message.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DecodeError> {
        match self.bytes.get(self.pos..self.pos.saturating_add(n)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => Err(DecodeError(format!(
                "truncated: {what} needs {n} bytes at offset {}, the message has {}",
                self.pos,
                self.bytes.len()
            ))),
        }
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N], DecodeError> {
        let mut b = [0u8; N];
        b.copy_from_slice(self.take(N, what)?);
        Ok(b)
    }

    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1, "uint8")?[0])
    }

    fn u32(&mut self) -> Result<u32, DecodeError> {
        self.array("uint32").map(u32::from_le_bytes)
    }

    fn f64(&mut self) -> Result<f64, DecodeError> {
        self.array("float64").map(f64::from_le_bytes)
    }

    fn f64s<const N: usize>(&mut self) -> Result<[f64; N], DecodeError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64()?;
        }
        Ok(out)
    }

    /// An array count, checked against the bytes left (each element at
    /// least `min_size` bytes), so a corrupt count cannot ask for gigabytes.
    fn count(&mut self, min_size: usize) -> Result<usize, DecodeError> {
        let n = self.u32()? as usize;
        let left = self.bytes.len() - self.pos;
        if n.saturating_mul(min_size.max(1)) > left {
            return Err(DecodeError(format!(
                "array of {n} elements, only {left} bytes left"
            )));
        }
        Ok(n)
    }

    fn string(&mut self) -> Result<String, DecodeError> {
        let n = self.count(1)?;
        let s = self.take(n, "string")?;
        String::from_utf8(s.to_vec()).map_err(|_| DecodeError("string is not UTF-8".into()))
    }

    fn bytes(&mut self) -> Result<&'a [u8], DecodeError> {
        let n = self.count(1)?;
        self.take(n, "uint8[]")
    }

    fn f64_seq(&mut self) -> Result<Vec<f64>, DecodeError> {
        let n = self.count(8)?;
        (0..n).map(|_| self.f64()).collect()
    }

    fn header(&mut self) -> Result<Header, DecodeError> {
        let _seq = self.u32()?;
        let sec = self.u32()?;
        let nsec = self.u32()?;
        Ok(Header {
            stamp: f64::from(sec) + f64::from(nsec) * 1e-9,
            frame_id: self.string()?,
        })
    }

    fn pose(&mut self) -> Result<PoseMsg, DecodeError> {
        Ok(PoseMsg {
            translation: self.f64s::<3>()?,
            rotation: self.f64s::<4>()?,
        })
    }
}

fn reader(bytes: &[u8]) -> Reader<'_> {
    Reader { bytes, pos: 0 }
}

/// Decodes a `sensor_msgs/Image`.
pub fn image(bytes: &[u8]) -> Result<Image<'_>, DecodeError> {
    let mut r = reader(bytes);
    Ok(Image {
        header: r.header()?,
        height: r.u32()?,
        width: r.u32()?,
        encoding: r.string()?,
        is_bigendian: r.u8()? != 0,
        step: r.u32()?,
        data: r.bytes()?,
    })
}

/// Decodes a `sensor_msgs/CompressedImage`.
pub fn compressed_image(bytes: &[u8]) -> Result<CompressedImage<'_>, DecodeError> {
    let mut r = reader(bytes);
    Ok(CompressedImage {
        header: r.header()?,
        format: r.string()?,
        data: r.bytes()?,
    })
}

/// Decodes a `sensor_msgs/CameraInfo` (up to `K`).
pub fn camera_info(bytes: &[u8]) -> Result<CameraInfo, DecodeError> {
    let mut r = reader(bytes);
    let header = r.header()?;
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

/// Decodes a `geometry_msgs/PoseStamped`.
pub fn pose_stamped(bytes: &[u8]) -> Result<(Header, PoseMsg), DecodeError> {
    let mut r = reader(bytes);
    Ok((r.header()?, r.pose()?))
}

/// Decodes a `nav_msgs/Odometry`'s header and pose (its covariance and
/// twist are not read).
pub fn odometry(bytes: &[u8]) -> Result<(Header, PoseMsg), DecodeError> {
    let mut r = reader(bytes);
    let h = r.header()?;
    let _child = r.string()?;
    Ok((h, r.pose()?))
}

/// Decodes a `tf/tfMessage` or `tf2_msgs/TFMessage`.
pub fn tf_message(bytes: &[u8]) -> Result<Vec<Transform>, DecodeError> {
    let mut r = reader(bytes);
    // A TransformStamped is at least 16 (header) + 4 + 56 bytes.
    let n = r.count(76)?;
    (0..n)
        .map(|_| {
            Ok(Transform {
                header: r.header()?,
                child_frame_id: r.string()?,
                pose: r.pose()?,
            })
        })
        .collect()
}

/// Encodes ROS 1 messages (the mirror of the decoders), for tests and fuzz
/// seeds; `seq` is written as 0.
#[doc(hidden)]
pub mod encode {
    use super::*;

    fn u32(out: &mut Vec<u8>, v: u32) {
        out.extend_from_slice(&v.to_le_bytes());
    }

    fn bytes(out: &mut Vec<u8>, b: &[u8]) {
        u32(out, b.len() as u32);
        out.extend_from_slice(b);
    }

    fn f64s(out: &mut Vec<u8>, v: &[f64]) {
        for x in v {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }

    fn header(out: &mut Vec<u8>, h: &Header) {
        let sec = h.stamp.floor();
        let nsec = ((h.stamp - sec) * 1e9).round().min(999_999_999.0);
        u32(out, 0);
        u32(out, sec as u32);
        u32(out, nsec as u32);
        bytes(out, h.frame_id.as_bytes());
    }

    fn pose(out: &mut Vec<u8>, p: &PoseMsg) {
        f64s(out, &p.translation);
        f64s(out, &p.rotation);
    }

    /// A `sensor_msgs/Image`.
    pub fn image(m: &Image<'_>) -> Vec<u8> {
        let mut out = Vec::new();
        header(&mut out, &m.header);
        u32(&mut out, m.height);
        u32(&mut out, m.width);
        bytes(&mut out, m.encoding.as_bytes());
        out.push(u8::from(m.is_bigendian));
        u32(&mut out, m.step);
        bytes(&mut out, m.data);
        out
    }

    /// A `sensor_msgs/CompressedImage`.
    pub fn compressed_image(m: &CompressedImage<'_>) -> Vec<u8> {
        let mut out = Vec::new();
        header(&mut out, &m.header);
        bytes(&mut out, m.format.as_bytes());
        bytes(&mut out, m.data);
        out
    }

    /// A `sensor_msgs/CameraInfo` (plumb_bob; `R` identity, `P` from `K`,
    /// no binning, no ROI).
    pub fn camera_info(m: &CameraInfo) -> Vec<u8> {
        let mut out = Vec::new();
        header(&mut out, &m.header);
        u32(&mut out, m.height);
        u32(&mut out, m.width);
        bytes(&mut out, b"plumb_bob");
        u32(&mut out, m.d.len() as u32);
        f64s(&mut out, &m.d);
        f64s(&mut out, &m.k);
        f64s(&mut out, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
        let k = &m.k;
        f64s(
            &mut out,
            &[
                k[0], k[1], k[2], 0.0, k[3], k[4], k[5], 0.0, k[6], k[7], k[8], 0.0,
            ],
        );
        // binning_x, binning_y; RegionOfInterest: 4 x u32 and do_rectify.
        out.extend_from_slice(&[0; 8 + 16 + 1]);
        out
    }

    /// A `geometry_msgs/PoseStamped`.
    pub fn pose_stamped(h: &Header, p: &PoseMsg) -> Vec<u8> {
        let mut out = Vec::new();
        header(&mut out, h);
        pose(&mut out, p);
        out
    }

    /// A `nav_msgs/Odometry` with zero covariance and twist.
    pub fn odometry(h: &Header, child: &str, p: &PoseMsg) -> Vec<u8> {
        let mut out = Vec::new();
        header(&mut out, h);
        bytes(&mut out, child.as_bytes());
        pose(&mut out, p);
        f64s(&mut out, &[0.0; 36 + 6 + 36]);
        out
    }

    /// A `tf2_msgs/TFMessage`.
    pub fn tf_message(transforms: &[Transform]) -> Vec<u8> {
        let mut out = Vec::new();
        u32(&mut out, transforms.len() as u32);
        for t in transforms {
            header(&mut out, &t.header);
            bytes(&mut out, t.child_frame_id.as_bytes());
            pose(&mut out, &t.pose);
        }
        out
    }
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
        assert_eq!(image(&encode::image(&img)).unwrap(), img);
        let c = CompressedImage {
            header: h(1.5, "cam"),
            format: "16UC1; compressedDepth png".into(),
            data: &data,
        };
        assert_eq!(compressed_image(&encode::compressed_image(&c)).unwrap(), c);
        let info = CameraInfo {
            header: h(1.0, "cam"),
            height: 480,
            width: 640,
            d: vec![0.0; 5],
            k: [585.0, 0.0, 320.0, 0.0, 585.0, 240.0, 0.0, 0.0, 1.0],
        };
        assert_eq!(camera_info(&encode::camera_info(&info)).unwrap(), info);
        assert_eq!(
            pose_stamped(&encode::pose_stamped(&h(2.5, "map"), &P)).unwrap(),
            (h(2.5, "map"), P)
        );
        assert_eq!(
            odometry(&encode::odometry(&h(3.0, "odom"), "base", &P)).unwrap(),
            (h(3.0, "odom"), P)
        );
        let tf = vec![Transform {
            header: h(4.0, "map"),
            child_frame_id: "camera_optical".into(),
            pose: P,
        }];
        assert_eq!(tf_message(&encode::tf_message(&tf)).unwrap(), tf);
    }

    #[test]
    fn a_known_ros1_image_decodes_and_any_cut_is_refused() {
        // A 2x1 16UC1 image as rospy serializes it (seq 7, stamp 5 s 6 ns, frame "f").
        let bytes: Vec<u8> = [
            &7u32.to_le_bytes()[..],
            &5u32.to_le_bytes(),
            &6u32.to_le_bytes(),
            &1u32.to_le_bytes(),
            b"f",
            &1u32.to_le_bytes(),
            &2u32.to_le_bytes(),
            &5u32.to_le_bytes(),
            b"16UC1",
            &[1], // is_bigendian
            &4u32.to_le_bytes(),
            &4u32.to_le_bytes(),
            &[0x03, 0xe8, 0x00, 0x01],
        ]
        .concat();
        let img = image(&bytes).unwrap();
        assert_eq!(img.header, h(5.0 + 6e-9, "f"));
        assert_eq!((img.width, img.height, img.step), (2, 1, 4));
        assert_eq!(img.encoding, "16UC1");
        assert!(img.is_bigendian);
        assert_eq!(img.data, [0x03, 0xe8, 0x00, 0x01]);
        for n in 0..bytes.len() {
            assert!(image(&bytes[..n]).is_err(), "cut at {n}");
        }
        // A count that the bytes cannot hold is refused before allocating.
        let e = tf_message(&u32::MAX.to_le_bytes()).unwrap_err();
        assert!(e.0.contains("4294967295 elements"), "{e}");
    }
}
