//! The office floor: a corridor along world x with rooms off both sides, every
//! room furnished alike (desks, chairs, monitors, cabinets, doors) with small
//! seeded variations — the repetitive case that makes place recognition hard.
//!
//! World frame: metres, **z up**, x east along the corridor, y north. The
//! origin is where the camera's walk starts: on the corridor's centre line,
//! 1.03 m from the west end wall, at eye height [`EYE_HEIGHT`] = 1.37 m above
//! the floor; so the floor is z = [`FLOOR_Z`] = -1.37 and the ceiling
//! z = 1.33. These odd numbers keep every large plane (floor, ceiling, walls at
//! y = ±1.05, ±1.15, ±6.15, x = -1.03 + 2 + 4k ± 0.05) off the voxel boundaries
//! of the usual voxel sizes (0.1, 0.2, 0.25, 0.3, 0.5 m anchored at the origin),
//! where depth rounding would make a wall's points flip between two voxels.
//! Rooms are numbered from the west, even numbers north (y > 0), odd south.
//! Every surface is an axis-aligned box.

use super::grid::Grid;
pub use super::scene_box::{Material, SceneBox};
use super::SynthConfig;
use crate::rng::SplitMix64;

/// Floor-to-ceiling height, metres.
pub const CEILING_HEIGHT: f64 = 2.7;
/// Height of the camera's eyes (the world origin) above the floor, metres.
pub const EYE_HEIGHT: f64 = 1.37;
/// World z of the floor.
pub const FLOOR_Z: f64 = -EYE_HEIGHT;
/// Distance from the west end wall to the world origin, metres.
const WEST_WALL_DISTANCE: f64 = 1.03;
/// Half the corridor's clear width, metres (walls' corridor faces at y = ±1.05).
pub const CORRIDOR_HALF_WIDTH: f64 = 1.05;
/// Wall thickness, metres.
pub const WALL: f64 = 0.1;
/// Distance between room partitions along x, metres.
pub const ROOM_PITCH: f64 = 4.0;
/// Clear depth of a room, from the corridor wall to the back wall, metres.
pub const ROOM_DEPTH: f64 = 5.0;
/// Length of the corridor beyond the rooms at each end, metres.
pub const LOBBY: f64 = 2.0;
/// Door opening width and height, metres.
pub const DOOR: (f64, f64) = (0.9, 2.1);
/// Grid cell edge for ray casting, metres.
const CELL: f64 = 0.5;

/// One room off the corridor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Room {
    /// North (y > 0) or south of the corridor.
    pub north: bool,
    /// Interior extent along x (world), metres.
    pub x_range: [f64; 2],
    /// x of the door's centre line.
    pub door_x: f64,
    /// The room's centre on the floor plan `[x, y]`: kept free of furniture.
    pub center: [f64; 2],
}

impl Room {
    /// +1 for north rooms, -1 for south rooms: the sign of y inside.
    pub fn side(&self) -> f64 {
        if self.north {
            1.0
        } else {
            -1.0
        }
    }
}

/// A furnished office floor and its ray-casting index.
#[derive(Debug, Clone)]
pub struct Scene {
    boxes: Vec<SceneBox>,
    rooms: Vec<Room>,
    x_range: [f64; 2],
    pub(crate) grid: Grid,
}

impl Scene {
    /// The office of `cfg.rooms` rooms, alternately north and south of the
    /// corridor (room 0 north), furnished from `cfg.seed`.
    pub fn office(cfg: &SynthConfig) -> Scene {
        let columns = cfg.rooms.div_ceil(2);
        let length = 2.0 * LOBBY + columns as f64 * ROOM_PITCH;
        let mut b = Builder::default();
        shell(&mut b, length, columns);
        let mut rooms = Vec::with_capacity(cfg.rooms);
        for k in 0..cfg.rooms {
            let x0 = LOBBY + (k / 2) as f64 * ROOM_PITCH + WALL / 2.0;
            let mut frame = RoomFrame {
                x_range: [x0, x0 + ROOM_PITCH - WALL],
                north: k % 2 == 0,
            };
            let mut rng = SplitMix64::stream(cfg.seed, k as u64);
            rooms.push(furnish(&mut b, &mut frame, &mut rng));
        }
        corridor(&mut b, length, &rooms);
        // Rooms were described in plan coordinates; the scene's are world.
        for r in &mut rooms {
            r.x_range = r.x_range.map(|x| x - WEST_WALL_DISTANCE);
            r.door_x -= WEST_WALL_DISTANCE;
            r.center[0] -= WEST_WALL_DISTANCE;
        }
        let grid = Grid::build(&b.boxes, CELL);
        Scene {
            boxes: b.boxes,
            rooms,
            x_range: [-WEST_WALL_DISTANCE, length - WEST_WALL_DISTANCE],
            grid,
        }
    }

    /// Every box of the scene.
    pub fn boxes(&self) -> &[SceneBox] {
        &self.boxes
    }

    /// The rooms, in room number order.
    pub fn rooms(&self) -> &[Room] {
        &self.rooms
    }

    /// World x of the corridor's west and east end walls (clear faces).
    pub fn x_range(&self) -> [f64; 2] {
        self.x_range
    }

    /// Distance along the unit direction `dir` from `origin` to the first
    /// surface (the ground truth of every rendered pixel); `None` when the ray
    /// leaves the building without hitting anything. From inside a box it is
    /// the distance to where the ray leaves it.
    pub fn ray_distance(&self, origin: [f64; 3], dir: [f64; 3]) -> Option<f64> {
        self.grid.cast(origin, dir, f64::INFINITY).map(|hit| hit.t)
    }

    /// The box hit first along `dir` from `origin` within `max` (in units of
    /// `dir`'s length): its index in [`Scene::boxes`] and the distance.
    pub fn first_hit(&self, origin: [f64; 3], dir: [f64; 3], max: f64) -> Option<(usize, f64)> {
        self.grid
            .cast(origin, dir, max)
            .map(|hit| (hit.id as usize, hit.t))
    }
}

/// Collects boxes given in plan coordinates (x from the west end wall, z from
/// the floor) and stores them in world coordinates.
#[derive(Default)]
struct Builder {
    boxes: Vec<SceneBox>,
}

impl Builder {
    fn add(&mut self, min: [f64; 3], max: [f64; 3], material: Material) {
        debug_assert!((0..3).all(|a| min[a] < max[a]));
        let world = |p: [f64; 3]| [p[0] - WEST_WALL_DISTANCE, p[1], p[2] + FLOOR_Z];
        self.boxes.push(SceneBox {
            min: world(min),
            max: world(max),
            material,
        });
    }
}

/// Floor, ceiling, outer walls, corridor walls (doors cut later) and partitions.
fn shell(b: &mut Builder, length: f64, columns: usize) {
    let h = CEILING_HEIGHT;
    let y_out = CORRIDOR_HALF_WIDTH + WALL + ROOM_DEPTH + WALL;
    let (x_lo, x_hi) = (-WALL, length + WALL);
    b.add([x_lo, -y_out, -0.1], [x_hi, y_out, 0.0], Material::Floor);
    b.add([x_lo, -y_out, h], [x_hi, y_out, h + 0.1], Material::Ceiling);
    b.add([x_lo, -y_out, 0.0], [0.0, y_out, h], Material::Wall);
    b.add([length, -y_out, 0.0], [x_hi, y_out, h], Material::Wall);
    b.add([0.0, y_out - WALL, 0.0], [length, y_out, h], Material::Wall);
    b.add(
        [0.0, -y_out, 0.0],
        [length, -y_out + WALL, h],
        Material::Wall,
    );
    let inner = CORRIDOR_HALF_WIDTH + WALL;
    for c in 0..=columns {
        let x = LOBBY + c as f64 * ROOM_PITCH;
        let (x0, x1) = (x - WALL / 2.0, x + WALL / 2.0);
        b.add([x0, inner, 0.0], [x1, y_out - WALL, h], Material::Wall);
        b.add([x0, -y_out + WALL, 0.0], [x1, -inner, h], Material::Wall);
    }
}

/// Corridor walls with the doors of `rooms` cut out, lights and corridor decor.
fn corridor(b: &mut Builder, length: f64, rooms: &[Room]) {
    let h = CEILING_HEIGHT;
    let (w0, w1) = (CORRIDOR_HALF_WIDTH, CORRIDOR_HALF_WIDTH + WALL);
    for north in [true, false] {
        let (y0, y1) = if north { (w0, w1) } else { (-w1, -w0) };
        let mut doors: Vec<f64> = rooms
            .iter()
            .filter(|r| r.north == north)
            .map(|r| r.door_x)
            .collect();
        doors.sort_by(f64::total_cmp);
        let mut x = 0.0;
        for d in doors {
            let (a, c) = (d - DOOR.0 / 2.0, d + DOOR.0 / 2.0);
            b.add([x, y0, 0.0], [a, y1, h], Material::Wall);
            b.add([a, y0, DOOR.1], [c, y1, h], Material::Wall);
            x = c;
        }
        b.add([x, y0, 0.0], [length, y1, h], Material::Wall);
    }
    // Lights along the centre line, every 2.5 m.
    let mut x = 1.0;
    while x + 0.6 < length {
        b.add([x, -0.15, h - 0.06], [x + 0.6, 0.15, h], Material::Light);
        x += 2.5;
    }
    // A notice board beside each door, an extinguisher at every other partition.
    for r in rooms {
        let s = r.side();
        let (ya, yb) = ord(s * (CORRIDOR_HALF_WIDTH - 0.02), s * CORRIDOR_HALF_WIDTH);
        let (xa, xb) = ord(r.door_x + s * 0.9, r.door_x + s * 2.1);
        b.add([xa, ya, 1.0], [xb, yb, 1.8], Material::Screen);
    }
    let columns = ((length - 2.0 * LOBBY) / ROOM_PITCH).round() as usize;
    for c in (0..=columns).step_by(2) {
        let x = LOBBY + c as f64 * ROOM_PITCH;
        let s = if c % 4 == 0 { 1.0 } else { -1.0 };
        let (ya, yb) = ord(s * (CORRIDOR_HALF_WIDTH - 0.15), s * CORRIDOR_HALF_WIDTH);
        b.add([x - 0.15, ya, 0.9], [x + 0.15, yb, 1.5], Material::Decor);
    }
    // Lobbies: a bench at the west end, a plant at the east end.
    b.add([0.0, -0.7, 0.0], [0.45, 0.7, 0.45], Material::Decor);
    b.add(
        [length - 0.45, 0.45, 0.0],
        [length - 0.1, 0.85, 0.4],
        Material::Decor,
    );
    b.add(
        [length - 0.55, 0.35, 0.4],
        [length, 0.95, 1.2],
        Material::Decor,
    );
}

/// `(min, max)` of two numbers.
fn ord(a: f64, b: f64) -> (f64, f64) {
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

/// A room's local frame: `u` along the corridor wall from the door's side,
/// `w` away from the corridor. South rooms are north rooms turned 180°, so
/// every room looks the same from its door.
struct RoomFrame {
    x_range: [f64; 2],
    north: bool,
}

impl RoomFrame {
    /// Clear width along `u`.
    fn width(&self) -> f64 {
        self.x_range[1] - self.x_range[0]
    }

    /// World point of local `(u, w)`.
    fn point(&self, u: f64, w: f64) -> [f64; 2] {
        let y0 = CORRIDOR_HALF_WIDTH + WALL;
        if self.north {
            [self.x_range[0] + u, y0 + w]
        } else {
            [self.x_range[1] - u, -(y0 + w)]
        }
    }

    /// Adds the local box `u0..u1 x w0..w1 x z0..z1`.
    #[allow(clippy::too_many_arguments)]
    fn add(&self, b: &mut Builder, u: [f64; 2], w: [f64; 2], z: [f64; 2], m: Material) {
        let p = self.point(u[0], w[0]);
        let q = self.point(u[1], w[1]);
        let (x0, x1) = ord(p[0], q[0]);
        let (y0, y1) = ord(p[1], q[1]);
        b.add([x0, y0, z[0]], [x1, y1, z[1]], m);
    }
}

/// Which wall a desk stands against.
#[derive(Clone, Copy)]
enum Against {
    /// The back wall (`w = ROOM_DEPTH`), desk spanning `u` from the given start.
    Back(f64),
    /// The wall opposite the door side (`u = width`), spanning `w` from the start.
    Side(f64),
}

/// Maps desk-local `a` (along the wall) and `b` (distance from the wall) ranges
/// to room-local `u` and `w` ranges.
fn desk_frame(room: &RoomFrame, at: Against, a: [f64; 2], b: [f64; 2]) -> ([f64; 2], [f64; 2]) {
    match at {
        Against::Back(u0) => (
            [u0 + a[0], u0 + a[1]],
            [ROOM_DEPTH - b[1], ROOM_DEPTH - b[0]],
        ),
        Against::Side(w0) => (
            [room.width() - b[1], room.width() - b[0]],
            [w0 + a[0], w0 + a[1]],
        ),
    }
}

/// A desk 1.5 m x 0.75 m with a monitor, and a chair in front of it.
fn desk(b: &mut Builder, room: &RoomFrame, at: Against, rng: &mut SplitMix64) {
    let mut put = |a: [f64; 2], d: [f64; 2], z: [f64; 2], m: Material| {
        let (u, w) = desk_frame(room, at, a, d);
        room.add(b, u, w, z, m);
    };
    let len = 1.5;
    put([0.0, len], [0.05, 0.8], [0.72, 0.75], Material::Desk);
    put([0.02, 0.05], [0.07, 0.78], [0.0, 0.72], Material::Desk);
    put(
        [len - 0.05, len - 0.02],
        [0.07, 0.78],
        [0.0, 0.72],
        Material::Desk,
    );
    let mid = len / 2.0 + rng.range(-0.2, 0.2);
    put(
        [mid - 0.28, mid + 0.28],
        [0.33, 0.36],
        [0.92, 1.26],
        Material::Screen,
    );
    put(
        [mid - 0.04, mid + 0.04],
        [0.27, 0.33],
        [0.75, 0.92],
        Material::Screen,
    );
    // Chair: seat centre c along the desk, s from the wall; its back away from the desk.
    let c = len / 2.0 + rng.range(-0.3, 0.3);
    let s = 1.15 + rng.range(-0.1, 0.15);
    put(
        [c - 0.23, c + 0.23],
        [s - 0.23, s + 0.23],
        [0.44, 0.5],
        Material::Chair,
    );
    put(
        [c - 0.23, c + 0.23],
        [s + 0.23, s + 0.28],
        [0.55, 1.0],
        Material::Chair,
    );
    put(
        [c - 0.03, c + 0.03],
        [s - 0.03, s + 0.03],
        [0.08, 0.44],
        Material::Chair,
    );
    put(
        [c - 0.3, c + 0.3],
        [s - 0.03, s + 0.03],
        [0.02, 0.08],
        Material::Chair,
    );
    put(
        [c - 0.03, c + 0.03],
        [s - 0.3, s + 0.3],
        [0.02, 0.08],
        Material::Chair,
    );
}

/// Door leaf, desks, storage, whiteboard, plant and lights of one room.
fn furnish(b: &mut Builder, room: &mut RoomFrame, rng: &mut SplitMix64) -> Room {
    let w = room.width();
    let door_u = 0.45 + DOOR.0 / 2.0;
    // The open door leaf, hinged at the door's side, standing into the room.
    room.add(
        b,
        [0.39, 0.45],
        [0.0, 0.88],
        [0.01, DOOR.1 - 0.05],
        Material::Door,
    );
    // Two desks against the back wall.
    for k in 0..2 {
        let u0 = 0.35 + k as f64 * 1.75 + rng.range(-0.1, 0.1);
        desk(b, room, Against::Back(u0), rng);
    }
    // Often a third desk against the side wall.
    if rng.chance(0.6) {
        desk(b, room, Against::Side(1.25 + rng.range(-0.05, 0.05)), rng);
    }
    // A tall cabinet or an open bookshelf against the door-side wall.
    let (s0, s1) = (1.6 + rng.range(-0.1, 0.1), 2.6 + rng.range(-0.1, 0.1));
    if rng.chance(0.5) {
        room.add(b, [0.0, 0.45], [s0, s1], [0.0, 1.9], Material::Cabinet);
    } else {
        room.add(b, [0.0, 0.02], [s0, s1], [0.0, 1.85], Material::Cabinet);
        room.add(
            b,
            [0.02, 0.38],
            [s0, s0 + 0.03],
            [0.0, 1.85],
            Material::Cabinet,
        );
        room.add(
            b,
            [0.02, 0.38],
            [s1 - 0.03, s1],
            [0.0, 1.85],
            Material::Cabinet,
        );
        for k in 0..5 {
            let z = 0.05 + k as f64 * 0.45;
            room.add(
                b,
                [0.02, 0.38],
                [s0 + 0.03, s1 - 0.03],
                [z, z + 0.02],
                Material::Cabinet,
            );
            if k < 4 {
                // A row of books of random length and height.
                let a = s0 + 0.03 + rng.range(0.0, 0.3);
                let len = rng.range(0.2, s1 - 0.03 - a);
                let top = z + 0.02 + rng.range(0.18, 0.32);
                room.add(
                    b,
                    [0.04, 0.3],
                    [a, a + len],
                    [z + 0.02, top],
                    Material::Decor,
                );
            }
        }
    }
    // Whiteboard on the side wall, behind where a side desk would end.
    room.add(b, [w - 0.02, w], [2.95, 4.05], [0.9, 2.0], Material::Screen);
    // Sometimes a plant in the corner between the storage and the back desks.
    if rng.chance(0.4) {
        room.add(b, [0.1, 0.4], [3.05, 3.35], [0.0, 0.35], Material::Decor);
        room.add(b, [0.05, 0.45], [3.0, 3.4], [0.35, 1.1], Material::Decor);
    }
    for wc in [1.5, 3.5] {
        let h = CEILING_HEIGHT;
        room.add(
            b,
            [w / 2.0 - 0.6, w / 2.0 + 0.6],
            [wc - 0.15, wc + 0.15],
            [h - 0.06, h],
            Material::Light,
        );
    }
    let door = room.point(door_u, 0.0);
    Room {
        north: room.north,
        x_range: room.x_range,
        door_x: door[0],
        center: room.point(w / 2.0, ROOM_DEPTH / 2.0),
    }
}
