//! The top view that explains itself: around the map of [`crate::output::topview`]
//! a title (sequence, solver, mu, database size), the horizontal axes
//! named and ticked in metres, a scale bar, the database frames numbered,
//! every frame in its class's colour, and a legend for the shading, the
//! colours and the marks. Text is drawn with the built-in [`font`].

pub mod font;

use crate::output::topview::{
    class_colours, finite2, Frame, Marks, Projection, TopView, BACKGROUND, CLASS_PALETTE,
    DISC_RADIUS, GREY_DARK, GREY_LIGHT, INK,
};
use crate::picture::Image;
use font::{draw_text, text_height, text_width};

/// Scale of the text: image pixels per font pixel.
const TEXT_SCALE: i64 = 2;
/// Blank space around the picture's parts, pixels.
const PAD: i64 = 12;
/// Length of a database frame's view line, pixels: longer than the plain
/// picture's, so that it shows past the ring.
const VIEW_LENGTH: f64 = 14.0;
/// Shortest distance between two ticks, pixels (room for their labels).
const TICK_SPACING: f64 = 90.0;
/// Length of a tick, pixels.
const TICK: i64 = 6;

/// The frames' marks over a class-coloured trajectory: a dot per frame in
/// its class colour, and per database frame a view line in ink and a disc
/// in its colour, ringed in ink ([`TopView::paint_database`]).
pub fn mark_frames(img: &mut Image, frame: &Frame, view: &TopView, colours: &[[u8; 3]]) {
    for (k, &p) in view.positions.iter().enumerate() {
        if let (true, Some(&c)) = (finite2(p), colours.get(k)) {
            img.disc(frame.pixel(p), 1, c);
        }
    }
    let marks = Marks {
        view_length: VIEW_LENGTH,
        line: INK,
        ring: Some(INK),
    };
    view.paint_database(img, frame, &marks, |i| {
        colours.get(i).copied().unwrap_or(INK)
    });
}

/// What the title and the axes say.
#[derive(Debug, Clone, PartialEq)]
pub struct Caption {
    /// First line: what was selected.
    pub title: String,
    /// The map's projection, for the axis names.
    pub projection: Projection,
}

impl Caption {
    /// The caption of a selection: sequence, solver, mu and database size.
    pub fn of_selection(
        sequence: &str,
        solver: &str,
        mu: f32,
        database: usize,
        frames: usize,
        projection: Projection,
    ) -> Caption {
        Caption {
            title: format!(
                "{sequence}: {database} database frames of {frames}, solver {solver}, mu {mu}"
            ),
            projection,
        }
    }
}

/// The world axis and sign of the picture's right ("east") and up
/// ("north"): `(axis, sign)` with axis 0, 1, 2 for x, y, z. The same axes
/// name the coordinates of the VPR-evaluation export.
pub fn east_north(p: &Projection) -> ((usize, f64), (usize, f64)) {
    let (i, j) = p.axes();
    // Image down is `sign * e_j`, so up is `-sign * e_j`.
    ((i, 1.0), (j, -p.sign))
}

/// `+x`, `-z`, ...
pub fn axis_name((axis, sign): (usize, f64)) -> String {
    let name = ["x", "y", "z"].get(axis).copied().unwrap_or("?");
    format!("{}{name}", if sign < 0.0 { '-' } else { '+' })
}

/// The annotated picture and where its map lies in it.
#[derive(Debug, Clone)]
pub struct Annotated {
    /// The whole picture.
    pub image: Image,
    /// Top-left corner of the map inside it, pixels.
    pub map_origin: (i64, i64),
    /// The map's pixel mapping (`None` when there was nothing to draw).
    pub frame: Option<Frame>,
}

impl Annotated {
    /// The pixel of the picture holding plane point `p` of the view.
    pub fn pixel(&self, p: [f64; 2]) -> Option<(i64, i64)> {
        let (x, y) = self.frame?.pixel(p);
        Some((x + self.map_origin.0, y + self.map_origin.1))
    }
}

/// A tick spacing of 1, 2 or 5 times a power of ten metres, at least
/// [`TICK_SPACING`] pixels at `scale` pixels per metre.
pub fn tick_step(scale: f64) -> f64 {
    if !(scale.is_finite() && scale > 0.0) {
        return 1.0;
    }
    let want = TICK_SPACING / scale;
    let mut power = 10f64.powf(want.log10().floor());
    loop {
        for m in [1.0, 2.0, 5.0] {
            if m * power >= want {
                return m * power;
            }
        }
        power *= 10.0;
    }
}

/// A distance or coordinate in metres with as many decimals as `step` needs.
fn metres(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10()).ceil().max(0.0) as usize
    };
    let s = format!("{v:.decimals$}");
    // "-0" and "-0.0" read as zero.
    if s.trim_start_matches('-')
        .chars()
        .all(|c| c == '0' || c == '.')
    {
        s.trim_start_matches('-').to_string()
    } else {
        s
    }
}

fn blit(dst: &mut Image, src: &Image, (ox, oy): (i64, i64)) {
    for y in 0..i64::from(src.height) {
        for x in 0..i64::from(src.width) {
            if let Some(c) = src.pixel(x, y) {
                dst.set(ox + x, oy + y, c);
            }
        }
    }
}

fn rect(img: &mut Image, (x0, y0): (i64, i64), (x1, y1): (i64, i64), colour: [u8; 3]) {
    for y in y0..y1 {
        for x in x0..x1 {
            img.set(x, y, colour);
        }
    }
}

/// Renders `view` ([`TopView::render`]) and annotates it with `caption`.
pub fn render(view: &TopView, caption: &Caption) -> Annotated {
    let (mut map, frame) = view.render_mapped();
    let colours = class_colours(view);
    if let (Some(f), false) = (&frame, colours.is_empty()) {
        mark_frames(&mut map, f, view, &colours);
    }
    let line = text_height(TEXT_SCALE) + 8;
    let (east, north) = east_north(&caption.projection);
    let subtitle = format!(
        "seen from above; east (right) = world {}, north (up) = world {}, in metres",
        axis_name(east),
        axis_name(north)
    );
    let step = frame.map_or(1.0, |f| tick_step(f.scale));
    // Plane extent of the map image: east along x, north = -(second coordinate).
    let (mw, mh) = (i64::from(map.width), i64::from(map.height));
    let ticks = |f: &Frame| {
        let at = |x: i64, y: i64| {
            let e = f.min[0] + (x as f64 - margin_of(f).0) / f.scale;
            let n = -(f.min[1] + (y as f64 - margin_of(f).1) / f.scale);
            (e, n)
        };
        let (e0, n0) = at(0, mh);
        let (e1, n1) = at(mw, 0);
        let east_ticks: Vec<f64> = multiples(e0, e1, step);
        let north_ticks: Vec<f64> = multiples(n0, n1, step);
        (east_ticks, north_ticks)
    };
    let (east_ticks, north_ticks) = frame.as_ref().map(ticks).unwrap_or_default();
    let label_w = north_ticks
        .iter()
        .map(|&n| text_width(&metres(n, step), TEXT_SCALE))
        .max()
        .unwrap_or(0);
    let database = view
        .database
        .iter()
        .filter(|&&i| i < view.positions.len())
        .count();
    let legend = [
        format!(
            "shading: voxels in a {} m column, 1 (light) to {} (dark)",
            metres(view.cell, 0.01),
            view.columns.iter().map(|c| c.1).max().unwrap_or(0)
        ),
        "trajectory: every frame in the colour of its class (the database frame covering it)"
            .to_string(),
        format!(
            "ringed disc: a database frame, its number the frame index ({database} frames), a line its view"
        ),
    ];
    let left = PAD + label_w + TICK + 4;
    let text_w = [caption.title.as_str(), subtitle.as_str()]
        .iter()
        .map(|t| text_width(t, TEXT_SCALE))
        .chain(legend.iter().map(|t| 40 + text_width(t, TEXT_SCALE)))
        .max()
        .unwrap_or(0);
    let width = (left + mw + PAD).max(PAD + text_w + PAD);
    let top = PAD + 2 * line + PAD / 2;
    let below_map = TICK + 4 + line;
    let footer = line + 4 + legend.len() as i64 * line;
    let height = top + mh + below_map + footer + PAD;
    let mut img = Image::filled(width as u32, height as u32, BACKGROUND);
    draw_text(&mut img, (PAD, PAD), &caption.title, TEXT_SCALE, INK);
    draw_text(&mut img, (PAD, PAD + line), &subtitle, TEXT_SCALE, INK);
    let origin = (left, top);
    blit(&mut img, &map, origin);
    // The map's frame and its ticks.
    let (x0, y0, x1, y1) = (left - 1, top - 1, left + mw, top + mh);
    img.line((x0, y0), (x1, y0), INK);
    img.line((x0, y1), (x1, y1), INK);
    img.line((x0, y0), (x0, y1), INK);
    img.line((x1, y0), (x1, y1), INK);
    if let Some(f) = &frame {
        let (mx, my) = margin_of(f);
        for &e in &east_ticks {
            let x = left + (mx + (e - f.min[0]) * f.scale).floor() as i64;
            img.line((x, y1), (x, y1 + TICK), INK);
            let label = metres(e, step);
            let w = text_width(&label, TEXT_SCALE);
            draw_text(
                &mut img,
                (x - w / 2, y1 + TICK + 4),
                &label,
                TEXT_SCALE,
                INK,
            );
        }
        for &n in &north_ticks {
            let y = top + (my + (-n - f.min[1]) * f.scale).floor() as i64;
            img.line((x0 - TICK, y), (x0, y), INK);
            let label = metres(n, step);
            let w = text_width(&label, TEXT_SCALE);
            let h = text_height(TEXT_SCALE);
            draw_text(
                &mut img,
                (x0 - TICK - 4 - w, y - h / 2),
                &label,
                TEXT_SCALE,
                INK,
            );
        }
        number_database_frames(&mut img, origin, f, view);
    }
    // Footer: the scale bar, then the legend.
    let mut y = y1 + below_map + 4;
    if let Some(f) = &frame {
        let len = (step * f.scale).round() as i64;
        rect(&mut img, (PAD, y + 4), (PAD + len, y + 10), INK);
        let label = format!("{} m", metres(step, step));
        draw_text(&mut img, (PAD + len + 8, y), &label, TEXT_SCALE, INK);
    }
    y += line + 4;
    let swatch = |img: &mut Image, y: i64, k: usize| match k {
        0 => {
            for dx in 0..32 {
                let t = dx as f64 / 31.0;
                let g = (GREY_LIGHT - (GREY_LIGHT - GREY_DARK) * t).round() as u8;
                rect(img, (PAD + dx, y), (PAD + dx + 1, y + 14), [g; 3]);
            }
        }
        1 => {
            for (c, colour) in CLASS_PALETTE.iter().take(3).enumerate() {
                let x = PAD + 11 * c as i64;
                img.line((x, y + 10), (x + 10, y + 4), *colour);
                img.disc((x + 10, y + 4), 1, *colour);
            }
        }
        _ => {
            img.disc((PAD + 14, y + 7), DISC_RADIUS + 1, INK);
            img.disc((PAD + 14, y + 7), DISC_RADIUS, CLASS_PALETTE[0]);
        }
    };
    for (k, text) in legend.iter().enumerate() {
        swatch(&mut img, y, k);
        draw_text(&mut img, (PAD + 40, y), text, TEXT_SCALE, INK);
        y += line;
    }
    Annotated {
        image: img,
        map_origin: origin,
        frame,
    }
}

/// The map image's margin around its drawing area: where plane point
/// `min` lies, pixels.
fn margin_of(f: &Frame) -> (f64, f64) {
    let [x, y] = f.px(f.min);
    (x, y)
}

/// Multiples of `step` in `[lo, hi]` (either order).
fn multiples(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let (lo, hi) = (lo.min(hi), lo.max(hi));
    if !(lo.is_finite() && hi.is_finite() && step > 0.0) || (hi - lo) / step > 1000.0 {
        return Vec::new();
    }
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// Each database frame's index beside its disc, on a white box; a number
/// that would cover one drawn before it is left out (dense databases).
fn number_database_frames(img: &mut Image, origin: (i64, i64), f: &Frame, view: &TopView) {
    let mut taken: Vec<(i64, i64, i64, i64)> = Vec::new();
    let h = text_height(TEXT_SCALE);
    let mut database: Vec<usize> = view.database.clone();
    database.sort_unstable();
    database.dedup();
    for i in database {
        let Some(&p) = view.positions.get(i) else {
            continue;
        };
        if !finite2(p) {
            continue;
        }
        let (x, y) = f.pixel(p);
        let label = i.to_string();
        let w = text_width(&label, TEXT_SCALE);
        let (bx, by) = (
            origin.0 + x + DISC_RADIUS + 3,
            origin.1 + y - h - DISC_RADIUS,
        );
        let b = (bx - 2, by - 2, bx + w + 2, by + h + 2);
        let inside =
            b.0 >= 0 && b.1 >= 0 && b.2 < i64::from(img.width) && b.3 < i64::from(img.height);
        let overlaps = taken
            .iter()
            .any(|t| b.0 < t.2 && t.0 < b.2 && b.1 < t.3 && t.1 < b.3);
        if !inside || overlaps {
            continue;
        }
        rect(img, (b.0, b.1), (b.2, b.3), BACKGROUND);
        draw_text(img, (bx, by), &label, TEXT_SCALE, INK);
        taken.push(b);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames on a line far from the map, two classes.
    fn view() -> TopView {
        let positions: Vec<[f64; 2]> = (0..10).map(|k| [k as f64, 0.5 * k as f64]).collect();
        TopView {
            cell: 0.5,
            columns: vec![([-20.0, -3.0], 4), ([-19.5, -3.0], 1)],
            view_dirs: vec![[1.0, 0.0]; positions.len()],
            positions,
            database: vec![2, 7],
            classes: vec![2, 2, 2, 2, 2, 7, 7, 7, 7, 7],
        }
    }

    fn caption() -> Caption {
        Caption::of_selection("test", "greedy", 0.3, 2, 10, Projection::new((2, -1.0)))
    }

    #[test]
    fn every_pose_is_inside_and_in_its_class_colour() {
        let v = view();
        let a = render(&v, &caption());
        let colours = class_colours(&v);
        assert_eq!(colours[0], CLASS_PALETTE[0]);
        assert_eq!(colours[9], CLASS_PALETTE[1]);
        for (k, &p) in v.positions.iter().enumerate() {
            let (x, y) = a.pixel(p).unwrap();
            let inside = (0..i64::from(a.image.width)).contains(&x)
                && (0..i64::from(a.image.height)).contains(&y);
            assert!(inside, "frame {k} at {x},{y} outside the picture");
            assert_eq!(a.image.pixel(x, y), Some(colours[k]), "frame {k}");
        }
        // A database frame is ringed in ink.
        let (x, y) = a.pixel(v.positions[7]).unwrap();
        assert_eq!(a.image.pixel(x, y + DISC_RADIUS + 1), Some(INK));
        // Far map and trajectory both inside: the map's dark column too.
        let (x, y) = a.pixel([-20.0, -3.0]).unwrap();
        assert!(a
            .image
            .pixel(x, y)
            .is_some_and(|c| c[0] == c[1] && c[0] < 200));
    }

    #[test]
    fn the_picture_has_title_legend_and_frame_above_and_below_the_map() {
        let v = view();
        let a = render(&v, &caption());
        let (map, _) = v.render_mapped();
        let ink_rows = |y0: i64, y1: i64| {
            (y0..y1)
                .any(|y| (0..i64::from(a.image.width)).any(|x| a.image.pixel(x, y) == Some(INK)))
        };
        let (ox, oy) = a.map_origin;
        assert!(ink_rows(0, oy - 1), "no title");
        assert!(
            ink_rows(oy + i64::from(map.height) + 1, i64::from(a.image.height)),
            "no legend"
        );
        // The map's frame on its left.
        assert_eq!(a.image.pixel(ox - 1, oy + 5), Some(INK));
        assert!(a.image.width >= map.width && a.image.height > map.height);
    }

    #[test]
    fn no_classes_keeps_the_plain_colours() {
        let mut v = view();
        v.classes.clear();
        assert!(class_colours(&v).is_empty());
        let (img, frame) = v.render_mapped();
        let (x, y) = frame.unwrap().pixel(v.positions[2]);
        assert_eq!(img.pixel(x, y), Some(crate::output::topview::DATABASE));
    }

    #[test]
    fn ticks_are_round_and_far_enough_apart() {
        assert_eq!(tick_step(100.0), 1.0);
        assert_eq!(tick_step(128.0), 1.0);
        assert_eq!(tick_step(50.0), 2.0);
        assert_eq!(tick_step(1000.0), 0.1);
        assert_eq!(tick_step(20.0), 5.0);
        assert_eq!(metres(-0.0, 0.5), "0.0");
        assert_eq!(metres(2.0, 1.0), "2");
        assert_eq!(multiples(-0.2, 2.1, 1.0), vec![0.0, 1.0, 2.0]);
    }

    #[test]
    fn axis_names_follow_the_projection() {
        // y down (TUM, 7-Scenes): right = +z, up = -x.
        let p = Projection::new((1, 1.0));
        let (e, n) = east_north(&p);
        assert_eq!(
            (axis_name(e), axis_name(n)),
            ("+z".to_string(), "-x".to_string())
        );
        // z up: right = +x, up = +y.
        let (e, n) = east_north(&Projection::new((2, -1.0)));
        assert_eq!(
            (axis_name(e), axis_name(n)),
            ("+x".to_string(), "+y".to_string())
        );
    }
}
