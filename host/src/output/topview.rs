//! A picture of the result: a top view of the voxel map, the camera trajectory
//! and the database frames, written as an 8-bit RGB PNG.
//!
//! The work is split in two so that the drawing can be tested on plain data:
//! [`topview`] projects the sequence and the voxel sets onto the horizontal
//! plane ([`TopView`]), and [`TopView::render`] rasterises that into an
//! [`Image`] without touching the file system ([`Image::write_png`] writes it).

use crate::picture::Image;
use crate::sequence::Sequence;
use std::collections::HashMap;

/// White: nothing there.
pub const BACKGROUND: [u8; 3] = [255, 255, 255];
/// Colour of the camera trajectory.
pub const TRAJECTORY: [u8; 3] = [30, 80, 230];
/// Colour of the database frames (disc and view direction).
pub const DATABASE: [u8; 3] = [220, 20, 20];

/// Long side of the drawing area, pixels (before the voxel-size floor).
const TARGET_SIDE: f64 = 900.0;
/// Blank border around the drawing, pixels; larger than the view lines so
/// that they stay inside the image.
const MARGIN: u32 = 24;
/// Hard cap on the long side of the drawing area, pixels: keeps a far outlier
/// voxel from asking for gigabytes (the one-pixel-per-voxel floor yields then).
const MAX_SIDE: f64 = 8192.0;
/// Side of the blank image written when there is nothing to draw.
const BLANK_SIDE: u32 = 64;
/// Radius of the disc marking a database frame, pixels (the annotated
/// picture rings it one pixel wider).
pub const DISC_RADIUS: i64 = 4;
/// Length of the view-direction line of a database frame in the plain
/// picture, pixels (the annotated one draws its own length, see
/// [`crate::output::annotate`]).
const VIEW_LENGTH: f64 = 12.0;
/// Classes in turn take these colours (by the rank of their database frame),
/// none of them grey (the map) or white.
pub const CLASS_PALETTE: [[u8; 3]; 9] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [188, 189, 34],
    [23, 190, 207],
];
/// Text, frame, ticks, the ring of a database frame, and the trajectory of
/// a frame whose class is no database frame.
pub const INK: [u8; 3] = [20, 20, 20];
/// Lightest and darkest grey of an occupied column (the legend draws the ramp).
pub const GREY_LIGHT: f64 = 225.0;
pub const GREY_DARK: f64 = 50.0;

/// Everything the picture shows, already projected onto the horizontal plane
/// (metres, in image orientation: first coordinate to the right, second
/// downwards).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopView {
    /// Edge of a map cell (the voxel size), metres; cells are drawn at least
    /// one pixel wide unless the image would exceed its size cap.
    pub cell: f64,
    /// Occupied columns: centre of the cell and number of occupied voxels in
    /// the column (0 is drawn as background).
    pub columns: Vec<([f64; 2], u32)>,
    /// Camera positions in sequence order; non-finite ones are skipped and
    /// break the polyline.
    pub positions: Vec<[f64; 2]>,
    /// Per position: the camera's viewing direction (its z axis) projected onto
    /// the plane, any length; a near-zero vector draws no view line.
    pub view_dirs: Vec<[f64; 2]>,
    /// Indices into `positions` of the database frames; out-of-range indices
    /// are ignored.
    pub database: Vec<usize>,
    /// Per position, its class (the database frame that covers it); when
    /// given, every frame is drawn in its class's colour ([`class_colours`])
    /// and the database frames are left to the annotation
    /// ([`crate::output::annotate`]); empty: one trajectory colour.
    pub classes: Vec<usize>,
}

/// Pixel mapping of a [`TopView`]: `pixel = MARGIN + (p - min) * scale`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Plane coordinates at the drawing area's top-left corner, metres.
    pub min: [f64; 2],
    /// Pixels per metre.
    pub scale: f64,
}

impl Frame {
    /// Sub-pixel position of plane point `p`.
    pub fn px(&self, p: [f64; 2]) -> [f64; 2] {
        [
            MARGIN as f64 + (p[0] - self.min[0]) * self.scale,
            MARGIN as f64 + (p[1] - self.min[1]) * self.scale,
        ]
    }

    /// The pixel holding plane point `p`.
    pub fn pixel(&self, p: [f64; 2]) -> (i64, i64) {
        let [x, y] = self.px(p);
        (x.floor() as i64, y.floor() as i64)
    }
}

/// Whether a top-view position can be drawn (both coordinates finite).
pub(crate) fn finite2(p: [f64; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

impl TopView {
    /// The database frames that can be drawn: index and position.
    pub(crate) fn database_points(&self) -> impl Iterator<Item = (usize, [f64; 2])> + '_ {
        self.database
            .iter()
            .filter_map(|&i| self.positions.get(i).map(|p| (i, *p)))
            .filter(|(_, p)| finite2(*p))
    }

    /// The one painter of database frames, for the plain and the annotated
    /// picture alike: first every database frame's view direction, a line
    /// `marks.view_length` pixels long in `marks.line` (all lines before the
    /// discs, so that no line covers one), then each frame's disc of
    /// [`DISC_RADIUS`] in `disc(frame index)`, ringed one pixel wider in
    /// `marks.ring` when it is given.
    pub fn paint_database(
        &self,
        img: &mut Image,
        frame: &Frame,
        marks: &Marks,
        disc: impl Fn(usize) -> [u8; 3],
    ) {
        self.draw_view_lines(img, frame, marks.view_length, marks.line);
        for (i, p) in self.database_points() {
            if let Some(ring) = marks.ring {
                img.disc(frame.pixel(p), DISC_RADIUS + 1, ring);
            }
            img.disc(frame.pixel(p), DISC_RADIUS, disc(i));
        }
    }

    /// Each database frame's view direction, a line `length` pixels long
    /// in `colour`.
    fn draw_view_lines(&self, img: &mut Image, frame: &Frame, length: f64, colour: [u8; 3]) {
        for (i, p) in self.database_points() {
            let Some(&d) = self.view_dirs.get(i) else {
                continue;
            };
            let norm = (d[0] * d[0] + d[1] * d[1]).sqrt();
            if !(norm > 1e-6 && norm.is_finite()) {
                continue;
            }
            let [x, y] = frame.px(p);
            let end = [x + length * d[0] / norm, y + length * d[1] / norm];
            let end = (end[0].floor() as i64, end[1].floor() as i64);
            img.line(frame.pixel(p), end, colour);
        }
    }

    /// Rasterises the view: grey map columns (white background, darker = more
    /// voxels in the column, relative to the fullest column), the trajectory as
    /// a blue polyline, then database frames as red discs with a short red
    /// line in their view direction. With classes, the trajectory is drawn in
    /// their colours and the frames' marks are left to the annotation, which
    /// draws them its own way.
    ///
    /// The longer side of the bounding box of the columns and the positions is
    /// scaled to about 900 pixels, or more so that a cell is at least one
    /// pixel (capped at 8192), keeping the aspect ratio, with a 24-pixel
    /// margin. With nothing finite to draw the result is a blank 64 x 64
    /// image; a single point is drawn in a 1 m wide window.
    pub fn render(&self) -> Image {
        self.render_mapped().0
    }

    /// [`Self::render`] and its pixel mapping (`None` for the blank image).
    pub fn render_mapped(&self) -> (Image, Option<Frame>) {
        let cell = if self.cell.is_finite() && self.cell > 0.0 {
            self.cell
        } else {
            0.0
        };
        let half = cell / 2.0;
        let columns = || self.columns.iter().filter(|(c, n)| *n > 0 && finite2(*c));
        let mut min = [f64::INFINITY; 2];
        let mut max = [f64::NEG_INFINITY; 2];
        let mut grow = |lo: [f64; 2], hi: [f64; 2]| {
            for a in 0..2 {
                min[a] = min[a].min(lo[a]);
                max[a] = max[a].max(hi[a]);
            }
        };
        for (c, _) in columns() {
            grow([c[0] - half, c[1] - half], [c[0] + half, c[1] + half]);
        }
        for &p in self.positions.iter().filter(|p| finite2(**p)) {
            grow(p, p);
        }
        let blank = || (Image::filled(BLANK_SIDE, BLANK_SIDE, BACKGROUND), None);
        if !(min[0] <= max[0] && min[1] <= max[1]) {
            return blank();
        }
        let mut extent = [max[0] - min[0], max[1] - min[1]];
        let long = extent[0].max(extent[1]);
        if !long.is_finite() {
            return blank();
        }
        if long < 1e-9 {
            // One point: centre it in a 1 m window.
            for a in 0..2 {
                min[a] -= 0.5;
                extent[a] = 1.0;
            }
        }
        let long = extent[0].max(extent[1]);
        let mut scale = TARGET_SIDE / long;
        if cell > 0.0 && scale * cell < 1.0 {
            scale = 1.0 / cell;
        }
        scale = scale.min(MAX_SIDE / long);
        let side = |e: f64| (e * scale).ceil() as u32 + 1 + 2 * MARGIN;
        let mut img = Image::filled(side(extent[0]), side(extent[1]), BACKGROUND);
        let frame = Frame { min, scale };

        // Map: per pixel keep the darkest (fullest) column touching it.
        let full = columns().map(|(_, n)| *n).max().unwrap_or(1).max(1) as f64;
        for &(c, n) in columns() {
            let t = (n as f64 / full).sqrt();
            let g = (GREY_LIGHT - (GREY_LIGHT - GREY_DARK) * t).round() as u8;
            let lo = frame.px([c[0] - half, c[1] - half]);
            let hi = frame.px([c[0] + half, c[1] + half]);
            let (x0, y0) = (lo[0].floor() as i64, lo[1].floor() as i64);
            let x1 = (hi[0].floor() as i64).max(x0 + 1);
            let y1 = (hi[1].floor() as i64).max(y0 + 1);
            // The cell clipped to the image, a row's span at a time.
            let (w, h) = (i64::from(img.width), i64::from(img.height));
            let (x0, x1) = (x0.clamp(0, w), x1.clamp(0, w));
            for y in y0.clamp(0, h)..y1.clamp(0, h) {
                let row = 3 * (y * w) as usize;
                let span = &mut img.rgb[row + 3 * x0 as usize..row + 3 * x1 as usize];
                for p in span.chunks_exact_mut(3) {
                    if p[0] > g {
                        p.fill(g);
                    }
                }
            }
        }

        // Trajectory, each step in the colour of the frame it reaches.
        let colours = class_colours(self);
        let colour = |k: usize| colours.get(k).copied().unwrap_or(TRAJECTORY);
        let mut last: Option<(i64, i64)> = None;
        for (k, &p) in self.positions.iter().enumerate() {
            if !finite2(p) {
                last = None;
                continue;
            }
            let q = frame.pixel(p);
            match last {
                Some(a) => img.line(a, q, colour(k)),
                None => img.set(q.0, q.1, colour(k)),
            }
            last = Some(q);
        }
        if colours.is_empty() {
            let marks = Marks {
                view_length: VIEW_LENGTH,
                line: DATABASE,
                ring: None,
            };
            self.paint_database(&mut img, &frame, &marks, |_| DATABASE);
        }
        (img, Some(frame))
    }
}

/// How [`TopView::paint_database`] marks a database frame (its disc's
/// colour is the caller's, frame by frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marks {
    /// Length of the view-direction line, pixels.
    pub view_length: f64,
    /// Colour of the view-direction line.
    pub line: [u8; 3],
    /// Colour of a ring one pixel around the disc; `None`: no ring.
    pub ring: Option<[u8; 3]>,
}

/// Per position of `view`, the colour of its class; empty when the view
/// has no classes. A class is a database frame; the database frames in
/// ascending order take the palette's colours in turn, so that
/// neighbouring classes differ.
pub fn class_colours(view: &TopView) -> Vec<[u8; 3]> {
    if view.classes.is_empty() {
        return Vec::new();
    }
    let mut database = view.database.clone();
    database.sort_unstable();
    database.dedup();
    let rank: HashMap<usize, usize> = database.iter().enumerate().map(|(r, &d)| (d, r)).collect();
    view.classes
        .iter()
        .map(|c| match rank.get(c) {
            Some(r) => CLASS_PALETTE[r % CLASS_PALETTE.len()],
            None => INK,
        })
        .collect()
}

/// World axis that is vertical, and its sign.
///
/// `down` is the sum over frames of the camera's y axis in world coordinates
/// (images have y pointing down, so this is roughly "down"). The vertical axis
/// is the world axis with the largest absolute component; the sign is `+1`
/// when down is along `+axis` (y-down conventions of TUM / 7-Scenes) and `-1`
/// when along `-axis` (z up, as the synthetic scan). With no information
/// (all zero or not finite) it falls back to z up.
pub fn vertical_axis(down: [f64; 3]) -> (usize, f64) {
    let mut best = (2, -1.0);
    let mut largest = 0.0;
    for (a, &c) in down.iter().enumerate() {
        if c.is_finite() && c.abs() > largest {
            largest = c.abs();
            best = (a, if c > 0.0 { 1.0 } else { -1.0 });
        }
    }
    best
}

/// Projection of world points onto the horizontal plane, in image orientation.
///
/// With vertical axis `k`, sign `s` ("down" is `s * e_k`) and the two other
/// axes `i = k+1`, `j = k+2` (mod 3), a point maps to `(p_i, s * p_j)`: image
/// right is `e_i`, image down is `s * e_j`, and `e_i x s e_j = s e_k` points
/// into the picture, i.e. down: the map is seen from above, not mirrored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// The vertical world axis.
    pub vertical: usize,
    /// `+1` if down is along `+vertical`, `-1` otherwise.
    pub sign: f64,
}

impl Projection {
    /// The projection for vertical axis `vertical` and sign `sign`.
    pub fn new((vertical, sign): (usize, f64)) -> Projection {
        Projection { vertical, sign }
    }

    /// The two horizontal world axes, image right first.
    pub fn axes(&self) -> (usize, usize) {
        ((self.vertical + 1) % 3, (self.vertical + 2) % 3)
    }

    /// Image-plane coordinates of world vector or point `p`.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 2] {
        let (i, j) = self.axes();
        [p[i], self.sign * p[j]]
    }
}

/// Columns `y` and `z` of the rotation matrix of quaternion `[qx, qy, qz, qw]`
/// (the camera's y and z axes in world coordinates); `None` if it is not a
/// usable rotation.
fn camera_axes(q: [f64; 4]) -> Option<([f64; 3], [f64; 3])> {
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    if !(n.is_finite() && n > 1e-9) {
        return None;
    }
    let [x, y, z, w] = q.map(|c| c / n);
    let y_axis = [
        2.0 * (x * y - z * w),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z + x * w),
    ];
    let z_axis = [
        2.0 * (x * z + y * w),
        2.0 * (y * z - x * w),
        1.0 - 2.0 * (x * x + y * y),
    ];
    Some((y_axis, z_axis))
}

/// Projects the sequence and its voxel sets onto the horizontal plane, with
/// no database frames: the map and the trajectory do not depend on the
/// solver, so `select` projects them while it solves, and fills in
/// [`TopView::database`] after.
///
/// `sets[f]` holds the packed voxel keys of frame `f` on `grid`; they are
/// united (only their union matters), and every horizontal cell gets the
/// number of occupied voxels of its column. Words that are no key are
/// skipped.
///
/// The vertical world axis is not fixed by the formats (TUM and 7-Scenes
/// usually have y down, the synthetic scan has z up), so it is inferred from
/// the cameras: a camera's y axis points down in its image, so the mean over
/// frames of the camera y axis in world coordinates (second column of the
/// camera-to-world rotation) is roughly "down". The world axis with the
/// largest absolute mean component is taken as vertical, and the picture is
/// the projection onto the two others, seen from above (see [`Projection`]).
/// Without usable rotations z is taken as up.
pub fn project(seq: &Sequence, sets: &[Vec<u64>], grid: placedb::VoxelGrid) -> TopView {
    let axes: Vec<Option<([f64; 3], [f64; 3])>> =
        seq.frames.iter().map(|f| camera_axes(f.rotation)).collect();
    let proj = horizontal(&seq.frames);
    let (i, j) = proj.axes();

    let union = crate::yardstick::metrics::union(sets);
    let mut counts: HashMap<(i32, i32), u32> = HashMap::new();
    for key in union.into_iter().filter_map(placedb::VoxelKey::from_bits) {
        let (x, y, z) = key.coords();
        let c = [x, y, z];
        *counts.entry((c[i], c[j])).or_insert(0) += 1;
    }
    let size = grid.voxel_size as f64;
    let centre = |a: usize, c: i32| grid.origin[a] as f64 + (c as f64 + 0.5) * size;
    let columns = counts
        .into_iter()
        .map(|((ci, cj), n)| {
            let mut p = [0.0; 3];
            p[i] = centre(i, ci);
            p[j] = centre(j, cj);
            (proj.apply(p), n)
        })
        .collect();

    TopView {
        cell: size,
        columns,
        positions: seq
            .frames
            .iter()
            .map(|f| proj.apply(f.translation))
            .collect(),
        view_dirs: axes
            .iter()
            .map(|a| a.map_or([0.0; 2], |(_, z)| proj.apply(z)))
            .collect(),
        database: Vec::new(),
        classes: Vec::new(),
    }
}

/// The top view's projection of `frames` (see [`project`]): the vertical
/// axis from the mean camera y axis. The exports name their horizontal
/// axes by it, so that a map and an export agree.
pub fn horizontal(frames: &[crate::sequence::FrameInfo]) -> Projection {
    let mut down = [0.0; 3];
    for (y, _) in frames.iter().filter_map(|f| camera_axes(f.rotation)) {
        for a in 0..3 {
            down[a] += y[a];
        }
    }
    Projection::new(vertical_axis(down))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::ReadError;
    use crate::sequence::{CameraModel, DepthImage, DepthSource, Format, FrameInfo};
    use std::path::{Path, PathBuf};

    fn is_grey(p: [u8; 3]) -> bool {
        p[0] == p[1] && p[1] == p[2] && p[0] < 255
    }

    /// A square trajectory around a 4 x 4 block of columns, database frames 0 and 2.
    fn scene() -> TopView {
        let mut columns = Vec::new();
        for a in 0..4 {
            for b in 0..4 {
                columns.push(([a as f64 + 0.5, b as f64 + 0.5], 1 + a + b));
            }
        }
        TopView {
            cell: 1.0,
            columns,
            positions: vec![[-2.0, -2.0], [6.0, -2.0], [6.0, 6.0], [-2.0, 6.0]],
            view_dirs: vec![[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]],
            database: vec![0, 2],
            classes: Vec::new(),
        }
    }

    #[test]
    fn render_dimensions_and_colours() {
        let v = scene();
        let img = v.render();
        // 8 m square: 900 px drawing area plus margins, square.
        assert_eq!(img.width, img.height);
        assert!((900 + 2 * MARGIN..=902 + 2 * MARGIN).contains(&img.width));
        assert_eq!(img.rgb.len(), img.width as usize * img.height as usize * 3);
        let s = 900.0 / 8.0;
        let px = |p: [f64; 2]| {
            (
                (MARGIN as f64 + (p[0] + 2.0) * s).floor() as i64,
                (MARGIN as f64 + (p[1] + 2.0) * s).floor() as i64,
            )
        };
        // Database frames: red at the centre and within the disc.
        for &i in &v.database {
            let (x, y) = px(v.positions[i]);
            assert_eq!(img.pixel(x, y), Some(DATABASE));
            assert_eq!(img.pixel(x + 3, y), Some(DATABASE));
        }
        // View line of frame 0 points to +x, beyond the disc.
        let (x, y) = px(v.positions[0]);
        assert_eq!(img.pixel(x + 10, y), Some(DATABASE));
        assert_eq!(img.pixel(x - 10, y), Some(BACKGROUND));
        // Frame 1 is no database frame: trajectory blue there and on the edges.
        let (x, y) = px(v.positions[1]);
        assert_eq!(img.pixel(x, y), Some(TRAJECTORY));
        let (x, y) = px([2.0, -2.0]);
        assert_eq!(img.pixel(x, y), Some(TRAJECTORY));
        let (x, y) = px([6.0, 2.0]);
        assert_eq!(img.pixel(x, y), Some(TRAJECTORY));
        // Map: grey inside, darker where fuller, white outside.
        let light = img.pixel(px([0.5, 0.5]).0, px([0.5, 0.5]).1).unwrap();
        let dark = img.pixel(px([3.5, 3.5]).0, px([3.5, 3.5]).1).unwrap();
        assert!(is_grey(light) && is_grey(dark));
        assert!(dark[0] < light[0]);
        assert_eq!(dark, [GREY_DARK as u8; 3]);
        let (x, y) = px([5.0, 2.0]);
        assert_eq!(img.pixel(x, y), Some(BACKGROUND));
    }

    #[test]
    fn aspect_ratio_and_voxel_floor() {
        // 20 m x 5 m: landscape 4:1.
        let v = TopView {
            cell: 1.0,
            positions: vec![[0.0, 0.0], [20.0, 5.0]],
            ..TopView::default()
        };
        let img = v.render();
        let (w, h) = (img.width - 2 * MARGIN, img.height - 2 * MARGIN);
        assert!((900..=902).contains(&w), "{w}");
        assert!((225..=227).contains(&h), "{h}");
        // 2000 cells across: one pixel per cell wins over 900 px.
        let v = TopView {
            cell: 0.01,
            columns: vec![([0.005, 0.005], 1), ([19.995, 0.005], 1)],
            ..TopView::default()
        };
        let img = v.render();
        assert!((2000..=2002).contains(&(img.width - 2 * MARGIN)));
        assert!((2..=3).contains(&(img.height - 2 * MARGIN)));
        assert!(is_grey(img.pixel(MARGIN as i64, MARGIN as i64).unwrap()));
        // A far outlier does not blow up the image.
        let v = TopView {
            cell: 0.01,
            columns: vec![([0.0, 0.0], 1), ([1e6, 0.0], 1)],
            ..TopView::default()
        };
        assert!(v.render().width <= MAX_SIDE as u32 + 2 * MARGIN + 2);
    }

    #[test]
    fn degenerate_inputs_do_not_panic() {
        let blank = TopView::default().render();
        assert_eq!((blank.width, blank.height), (BLANK_SIDE, BLANK_SIDE));
        assert!(blank.rgb.iter().all(|&b| b == 255));
        // A single database frame looking straight down, bad indices, NaNs.
        let v = TopView {
            cell: 0.3,
            positions: vec![[1.0, 1.0], [f64::NAN, 0.0]],
            view_dirs: vec![[0.0, 0.0]],
            database: vec![0, 1, 7],
            ..TopView::default()
        };
        let img = v.render();
        let c = (img.width / 2) as i64;
        assert_eq!(img.pixel(c, c), Some(DATABASE));
        let v = TopView {
            cell: f64::NAN,
            columns: vec![([f64::INFINITY, 0.0], 3), ([0.0, 0.0], 0)],
            ..TopView::default()
        };
        assert_eq!(v.render().width, BLANK_SIDE);
    }

    #[test]
    fn vertical_axis_and_projection() {
        assert_eq!(vertical_axis([0.1, 0.9, -0.2]), (1, 1.0));
        assert_eq!(vertical_axis([0.1, 0.2, -0.9]), (2, -1.0));
        assert_eq!(vertical_axis([0.0; 3]), (2, -1.0));
        // z up: x to the right, y up the picture.
        let p = Projection::new((2, -1.0));
        assert_eq!(p.apply([1.0, 2.0, 3.0]), [1.0, -2.0]);
        // y down: z to the right, x down the picture; seen from above means
        // right x down = down (+y).
        let p = Projection::new((1, 1.0));
        assert_eq!(p.apply([1.0, 2.0, 3.0]), [3.0, 1.0]);
    }

    #[test]
    fn camera_axes_of_identity_and_turn() {
        let (y, z) = camera_axes([0.0, 0.0, 0.0, 1.0]).unwrap();
        assert_eq!((y, z), ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]));
        // 90 degrees about x: camera y -> world z, camera z -> world -y.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let (y, z) = camera_axes([h, 0.0, 0.0, h]).unwrap();
        assert!((y[2] - 1.0).abs() < 1e-12 && (z[1] + 1.0).abs() < 1e-12);
        assert!(camera_axes([0.0; 4]).is_none());
        assert!(camera_axes([f64::NAN, 0.0, 0.0, 1.0]).is_none());
    }

    struct NoDepth;

    impl DepthSource for NoDepth {
        fn depth(&self, _: usize) -> Result<DepthImage, ReadError> {
            Err(ReadError::Layout {
                path: PathBuf::from("test"),
                reason: "no depth".into(),
            })
        }
    }

    /// Frames along +x looking along +x, z up: camera x = -y, y = -z, z = +x.
    fn sequence(n: usize) -> Sequence {
        // Rotation with columns (0,-1,0), (0,0,-1), (1,0,0): q = (0.5, -0.5, 0.5, -0.5).
        let q = [0.5, -0.5, 0.5, -0.5];
        Sequence {
            name: "test".into(),
            root: None,
            format: Format::Synthetic,
            camera: CameraModel {
                fx: 100.0,
                fy: 100.0,
                cx: 32.0,
                cy: 24.0,
            },
            depth_scale: 1000.0,
            size: (64, 48),
            frames: (0..n)
                .map(|i| FrameInfo {
                    index: i,
                    timestamp: i as f64,
                    translation: [i as f64, 0.0, 1.5],
                    rotation: q,
                    depth_name: format!("{i}"),
                    color_path: None,
                })
                .collect(),
            clock: crate::sequence::Clock::Seconds,
            frames_skipped: 0,
            pose_interpolation: None,
            source: Box::new(NoDepth),
        }
    }

    fn temp(name: &str) -> PathBuf {
        std::env::temp_dir().join(format!("placedb-plot-{}-{name}", std::process::id()))
    }

    fn read_png(path: &Path) -> Image {
        let dec = png::Decoder::new(std::fs::File::open(path).unwrap());
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        assert_eq!(info.bit_depth, png::BitDepth::Eight);
        buf.truncate(info.buffer_size());
        Image {
            width: info.width,
            height: info.height,
            rgb: buf,
        }
    }

    #[test]
    fn project_infers_z_up_and_counts_columns() {
        let seq = sequence(3);
        let grid = placedb::VoxelGrid::new(0.5, [0.0; 3]).unwrap();
        let k = |x, y, z| placedb::VoxelKey::new(x, y, z).to_bits();
        let sets = vec![
            vec![k(2, 4, 0), k(2, 4, 1)],
            vec![k(2, 4, 1), k(2, 4, 5), k(-3, 0, 0), u64::MAX],
            vec![],
        ];
        let v = project(&seq, &sets, grid);
        let mut cols = v.columns.clone();
        cols.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
        // z up: (x, -y); column (2, 4) holds 3 voxels, (-3, 0) one.
        assert_eq!(cols, vec![([-1.25, -0.25], 1), ([1.25, -2.25], 3)]);
        assert_eq!(v.positions, vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]);
        for d in &v.view_dirs {
            assert!((d[0] - 1.0).abs() < 1e-12 && d[1].abs() < 1e-12);
        }
        assert!(v.database.is_empty());
    }

    #[test]
    fn topview_writes_png() {
        let grid = placedb::VoxelGrid::new(0.3, [0.0; 3]).unwrap();
        let k = |x, y, z| placedb::VoxelKey::new(x, y, z).to_bits();
        let sets: Vec<Vec<u64>> = (0..5)
            .map(|i| (0..4).map(|z| k(3 * i + 2, 5, z)).collect())
            .collect();
        let path = temp("five.png");
        let topview = |path: &Path, seq: &Sequence, sets: &[Vec<u64>], database: &[usize]| {
            let mut view = project(seq, sets, grid);
            view.database = database.to_vec();
            view.render().write_png(path)
        };
        topview(&path, &sequence(5), &sets, &[0, 4]).unwrap();
        let img = read_png(&path);
        assert!(img.width > img.height);
        assert!(img.rgb.chunks(3).any(|p| p == DATABASE));
        assert!(img.rgb.chunks(3).any(|p| p == TRAJECTORY));
        assert!(img.rgb.chunks(3).any(|p| is_grey([p[0], p[1], p[2]])));
        std::fs::remove_file(&path).ok();

        // Empty sequence, empty sets, single frame.
        let path = temp("empty.png");
        topview(&path, &sequence(0), &[], &[3]).unwrap();
        let img = read_png(&path);
        assert_eq!((img.width, img.height), (BLANK_SIDE, BLANK_SIDE));
        topview(&path, &sequence(1), &[vec![]], &[0]).unwrap();
        let img = read_png(&path);
        assert!(img.rgb.chunks(3).any(|p| p == DATABASE));
        std::fs::remove_file(&path).ok();
    }
}
