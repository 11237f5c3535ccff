//! Fuzz checks of the host's sequence readers, the paths that take bytes a
//! user's file holds: ROS 2 recordings (MCAP records, CDR messages), ROS 1
//! bags (the container's records and chunks, ROS 1 messages) and depth PNGs
//! (chunks, inflate, the row unfilter). Shared by the fuzz targets `ros2`,
//! `ros1` and `depth_png` and by `host/tests/fuzz_corpus_readers.rs`, which
//! replays the committed corpus through the same checks on stable.
//!
//! Every input must end in `Ok` or an error, never a panic, a hang or an
//! allocation out of proportion to the input; what decodes must be
//! consistent (sizes, frame order, round trips), and the decoders with a
//! fast path must agree with a plain one.

use placedb_host::read::ros2::wire::Wire;
use placedb_host::read::ros2::{self, bag, msgs, ros1_msgs, Ros2Options};
use placedb_host::read::{self, fuzzing, ReadOptions};
use placedb_host::vector_unit::VectorUnit;
use std::cell::Cell;
use std::path::{Path, PathBuf};

/// `compressed_depth` target: `data` as the payload of a depth
/// CompressedImage in every coding the reader takes (compressedDepth PNG
/// and RVL of depth and of inverse depth, a bare 16-bit PNG), as a CDR
/// CompressedImage message, and as a colour JPEG or PNG. A payload that decodes holds exactly its
/// claimed pixels, and the size read from its header alone is the size it
/// decodes to.
pub fn compressed_depth(data: &[u8]) {
    use ros2::depth_codec::{self, DepthCodec};
    let codings = [
        DepthCodec::CompressedDepth {
            inverse: false,
            rvl: false,
        },
        DepthCodec::CompressedDepth {
            inverse: false,
            rvl: true,
        },
        DepthCodec::CompressedDepth {
            inverse: true,
            rvl: false,
        },
        DepthCodec::CompressedDepth {
            inverse: true,
            rvl: true,
        },
        DepthCodec::Png,
    ];
    for codec in codings {
        let size = depth_codec::size(codec, data);
        if let Ok((w, h, values)) = depth_codec::decode(codec, data, 1000.0) {
            assert_eq!(values.len(), usize::from(w) * usize::from(h));
            assert_eq!(size, Ok((w, h)), "{codec:?}");
        }
    }
    if let Ok(img) = msgs::compressed_image(data) {
        if let Ok(codec) = depth_codec::codec(&img.format) {
            let _ = depth_codec::decode(codec, img.data, 1000.0);
        }
    }
    // The same bytes as a colour JPEG or PNG: RGB of exactly its pixels.
    use ros2::color_codec::{self, ColorCodec};
    for codec in [ColorCodec::Jpeg, ColorCodec::Png] {
        if let Ok(img) = color_codec::decode(codec, data) {
            assert_eq!(img.rgb.len(), 3 * img.width as usize * img.height as usize);
        }
    }
}

/// `ros2` target: `data` as one CDR message of every kind the reader
/// decodes, and as a `.mcap` file read by the full bag reader (with and
/// without a TF frame to take poses from).
pub fn ros2(data: &[u8]) {
    wire_messages(Wire::Cdr, &CDR, data);
    if data.starts_with(b"\x89MCAP") {
        whole_reader(&InputFile::new(data, "mcap"));
    }
}

/// `ros1` target: `data` as one ROS 1 message of every kind the reader
/// decodes, and as a `.bag` file: walked by the container alone (every
/// message it hands on reads back the same by its place) and read by the
/// full bag reader.
pub fn ros1(data: &[u8]) {
    wire_messages(Wire::Ros1, &ROS1, data);
    if data.starts_with(b"#ROSBAG V2.0\n") {
        let file = InputFile::new(data, "bag");
        container_walk(file.path());
        whole_reader(&file);
    }
}

/// The container's walk of the file at `path`: it ends in `Ok` or an error
/// in words, and every message it hands on (the first 64) is fetched back
/// byte for byte from its place.
fn container_walk(path: &Path) {
    let mut seen = Vec::new();
    match bag::scan(0, path, &|_| None, &mut |m| {
        if seen.len() < 64 {
            seen.push((m.at, m.data.to_vec()));
        }
        Ok(())
    }) {
        Ok(cut) => assert!(cut <= std::fs::metadata(path).map_or(0, |m| m.len())),
        Err((_, reason)) => assert!(!reason.is_empty()),
    }
    for (at, data) in seen {
        let back = bag::fetch(path, at).expect("a scanned message fetches back");
        assert!(back == data, "message at {} reads back different", at.place);
    }
}

/// A wire's encoders, to re-encode what its decoders ([`Wire`]) read.
struct Encoders {
    image: fn(&msgs::Image<'_>) -> Vec<u8>,
    compressed_image: fn(&msgs::CompressedImage<'_>) -> Vec<u8>,
    camera_info: fn(&msgs::CameraInfo) -> Vec<u8>,
    pose_stamped: fn(&msgs::Header, &msgs::PoseMsg) -> Vec<u8>,
    odometry: fn(&msgs::Header, &str, &msgs::PoseMsg) -> Vec<u8>,
    tf_message: fn(&[msgs::Transform]) -> Vec<u8>,
}

const CDR: Encoders = Encoders {
    image: msgs::encode_image,
    compressed_image: msgs::encode_compressed_image,
    camera_info: msgs::encode_camera_info,
    pose_stamped: msgs::encode_pose_stamped,
    odometry: msgs::encode_odometry,
    tf_message: msgs::encode_tf_message,
};

const ROS1: Encoders = Encoders {
    image: ros1_msgs::encode::image,
    compressed_image: ros1_msgs::encode::compressed_image,
    camera_info: ros1_msgs::encode::camera_info,
    pose_stamped: ros1_msgs::encode::pose_stamped,
    odometry: ros1_msgs::encode::odometry,
    tf_message: ros1_msgs::encode::tf_message,
};

/// `data` as one message of every kind the reader decodes on `wire`:
/// what decodes re-encodes (`enc`) to a message that decodes to the same
/// fields (stamps aside: a header's seconds and nanoseconds are kept as one
/// `f64`), and an image decodes to depth and colour of exactly its pixels.
fn wire_messages(wire: Wire, enc: &Encoders, data: &[u8]) {
    if let Ok(img) = wire.image(data) {
        let bytes = (enc.image)(&img);
        let back = wire
            .image(&bytes)
            .unwrap_or_else(|e| panic!("a re-encoded {wire:?} Image does not decode: {e}"));
        assert_eq!(
            (back.width, back.height, back.step, back.is_bigendian),
            (img.width, img.height, img.step, img.is_bigendian)
        );
        assert_eq!(
            (&back.encoding, &back.header.frame_id, back.data),
            (&img.encoding, &img.header.frame_id, img.data)
        );
        let pixels = img.width as usize * img.height as usize;
        for scale in [1000.0, 5000.0] {
            if let Ok(d) = ros2::decode_depth(&img, scale) {
                assert_eq!(d.data.len(), pixels);
                assert_eq!(
                    (u32::from(d.width), u32::from(d.height)),
                    (img.width, img.height)
                );
            }
        }
        if let Ok(c) = ros2::decode_color(&img) {
            assert_eq!(c.rgb.len(), 3 * pixels);
        }
    }
    if let Ok(c) = wire.compressed_image(data) {
        let bytes = (enc.compressed_image)(&c);
        let back = wire.compressed_image(&bytes).unwrap_or_else(|e| {
            panic!("a re-encoded {wire:?} CompressedImage does not decode: {e}")
        });
        assert_eq!((&back.format, back.data), (&c.format, c.data));
    }
    if let Ok(info) = wire.camera_info(data) {
        let back = wire
            .camera_info(&(enc.camera_info)(&info))
            .unwrap_or_else(|e| panic!("a re-encoded {wire:?} CameraInfo does not decode: {e}"));
        assert_eq!((back.width, back.height), (info.width, info.height));
        assert_eq!(bits(&back.k), bits(&info.k));
        assert_eq!(bits(&back.d), bits(&info.d));
    }
    if let Ok((h, p)) = wire.pose_stamped(data) {
        let (back_h, back) = wire
            .pose_stamped(&(enc.pose_stamped)(&h, &p))
            .unwrap_or_else(|e| panic!("a re-encoded {wire:?} PoseStamped does not decode: {e}"));
        assert_eq!(back_h.frame_id, h.frame_id);
        assert_eq!(pose_bits(&back), pose_bits(&p));
    }
    if let Ok((h, p)) = wire.odometry(data) {
        let (_, back) = wire
            .odometry(&(enc.odometry)(&h, "child", &p))
            .unwrap_or_else(|e| panic!("a re-encoded {wire:?} Odometry does not decode: {e}"));
        assert_eq!(pose_bits(&back), pose_bits(&p));
    }
    if let Ok(tf) = wire.tf_message(data) {
        let back = wire
            .tf_message(&(enc.tf_message)(&tf))
            .unwrap_or_else(|e| panic!("a re-encoded {wire:?} TFMessage does not decode: {e}"));
        assert_eq!(back.len(), tf.len());
        for (b, t) in back.iter().zip(&tf) {
            assert_eq!(b.child_frame_id, t.child_frame_id);
            assert_eq!(pose_bits(&b.pose), pose_bits(&t.pose));
        }
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn pose_bits(p: &msgs::PoseMsg) -> Vec<u64> {
    let mut v = bits(&p.translation);
    v.extend(bits(&p.rotation));
    v
}

thread_local! {
    /// How many inputs this thread has written, for a fresh file name each
    /// time (the reader must not see an earlier input's file).
    static WRITTEN: Cell<u64> = const { Cell::new(0) };
}

/// A file of this process and thread holding `data`, removed after use.
struct InputFile(PathBuf);

impl InputFile {
    fn new(data: &[u8], ext: &str) -> InputFile {
        let n = WRITTEN.with(|w| {
            w.set(w.get() + 1);
            w.get()
        });
        let thread = format!("{:?}", std::thread::current().id());
        let name: String = thread.chars().filter(char::is_ascii_digit).collect();
        let path = std::env::temp_dir().join(format!(
            "placedb-fuzz-{}-{name}-{}.{ext}",
            std::process::id(),
            n % 2
        ));
        std::fs::write(&path, data).expect("write the fuzz input to a temp file");
        InputFile(path)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for InputFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The whole bag reader on `file` (a `.mcap` or `.bag` file): a read that
/// succeeds has frames in time order, indexed by position, with unit
/// rotations and the sequence's size, and every frame's depth (and colour)
/// decodes or fails with an error, the depth at the sequence's size.
fn whole_reader(file: &InputFile) {
    for pose_frame in [None, Some("camera".to_string())] {
        let opts = ReadOptions {
            ros2: Ros2Options {
                pose_frame,
                ..Ros2Options::default()
            },
            ..ReadOptions::default()
        };
        let seq = match read::open(file.path(), &opts) {
            Ok(seq) => seq,
            Err(e) => {
                assert!(!e.to_string().is_empty());
                continue;
            }
        };
        assert!(!seq.frames.is_empty());
        assert!(seq.size.0 > 0 && seq.size.1 > 0);
        for (i, f) in seq.frames.iter().enumerate() {
            assert_eq!(f.index, i);
            let norm: f64 = f.rotation.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!(
                (norm - 1.0).abs() < 1e-6,
                "frame {i}: rotation {:?}",
                f.rotation
            );
        }
        assert!(seq
            .frames
            .windows(2)
            .all(|w| w[0].timestamp <= w[1].timestamp));
        for i in 0..seq.frames.len().min(4) {
            if let Ok(d) = seq.depth(i) {
                assert_eq!((d.width, d.height), seq.size);
                assert_eq!(d.data.len(), usize::from(d.width) * usize::from(d.height));
            }
            if let Ok(Some(c)) = seq.source.color(i) {
                assert_eq!(c.rgb.len(), 3 * c.width as usize * c.height as usize);
            }
        }
    }
}

/// `depth_png` target. Byte 0: bit 0 asks for 7-Scenes' "65535 is no
/// measurement", bits 1-7 are the width (1..=128 pixels) at which the rest
/// is unfiltered as raw scanlines. The rest: a depth PNG for the reader's
/// decoder, whose pixels must equal the `png` crate's whenever both
/// decode; and scanlines, whose unfiltering on every vector unit this CPU
/// has must equal the specification's, error included.
pub fn depth_png(data: &[u8]) {
    let Some((&flags, rest)) = data.split_first() else {
        return;
    };
    png_file(rest, flags & 1 == 1);
    unfilter(rest, 2 * (usize::from(flags >> 1) + 1));
}

fn png_file(bytes: &[u8], invalid_65535: bool) {
    let Ok(img) = fuzzing::decode_depth_png(Path::new("fuzz.png"), bytes, invalid_65535) else {
        return;
    };
    let (w, h) = (usize::from(img.width), usize::from(img.height));
    assert!(w > 0 && h > 0);
    assert_eq!(img.data.len(), w * h);
    if invalid_65535 {
        assert!(!img.data.contains(&u16::MAX));
    }
    // The png crate, with its default memory limits, as the reference.
    let mut decoder = png::Decoder::new(bytes);
    decoder.set_transformations(png::Transformations::IDENTITY);
    let Ok(mut reader) = decoder.read_info() else {
        return;
    };
    let mut raw = vec![0u8; reader.output_buffer_size()];
    let Ok(info) = reader.next_frame(&mut raw) else {
        return;
    };
    if info.bit_depth != png::BitDepth::Sixteen || info.color_type != png::ColorType::Grayscale {
        panic!(
            "decoded a {:?} {:?} image as depth",
            info.bit_depth, info.color_type
        );
    }
    assert_eq!((info.width as usize, info.height as usize), (w, h));
    let reference = raw[..info.buffer_size()].chunks_exact(2).map(|px| {
        let v = u16::from_be_bytes([px[0], px[1]]);
        if invalid_65535 && v == u16::MAX {
            0
        } else {
            v
        }
    });
    assert!(
        img.data.iter().copied().eq(reference),
        "pixels differ from the png crate's"
    );
}

fn unfilter(bytes: &[u8], row_bytes: usize) {
    let line = row_bytes + 1;
    let whole = bytes.len() / line * line;
    let mut expected = bytes[..whole].to_vec();
    let expected_result = unfilter_reference(&mut expected, row_bytes);
    for unit in VectorUnit::available() {
        let mut got = bytes[..whole].to_vec();
        let result = fuzzing::unfilter(unit, &mut got, row_bytes);
        assert_eq!(result, expected_result, "{unit:?}: filter error");
        assert!(
            got == expected,
            "{unit:?}: rows differ from the specification's"
        );
    }
}

/// PNG unfiltering as the specification writes it, two bytes a pixel; stops
/// at the first unknown filter type, leaving that row and the later ones.
fn unfilter_reference(scanlines: &mut [u8], row_bytes: usize) -> Result<(), u8> {
    let mut above = vec![0u8; row_bytes];
    for line in scanlines.chunks_exact_mut(row_bytes + 1) {
        let (filter, row) = line.split_at_mut(1);
        if filter[0] > 4 {
            return Err(filter[0]);
        }
        for i in 0..row_bytes {
            let a = if i >= 2 { row[i - 2] } else { 0 };
            let b = above[i];
            let c = if i >= 2 { above[i - 2] } else { 0 };
            let predicted = match filter[0] {
                0 => 0,
                1 => a,
                2 => b,
                3 => ((u16::from(a) + u16::from(b)) / 2) as u8,
                _ => paeth(a, b, c),
            };
            row[i] = row[i].wrapping_add(predicted);
        }
        above.copy_from_slice(row);
    }
    Ok(())
}

fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let p = i16::from(a) + i16::from(b) - i16::from(c);
    let (pa, pb, pc) = (
        (p - i16::from(a)).abs(),
        (p - i16::from(b)).abs(),
        (p - i16::from(c)).abs(),
    );
    if pa <= pb && pa <= pc {
        a
    } else if pb <= pc {
        b
    } else {
        c
    }
}
