//! [`SceneBox`], the one shape of the synthetic scenes (every surface is an
//! axis-aligned box), and its [`Material`]: what the scene is built of and
//! what the ray-casting grid holds.

/// What a box is, for pictures and debugging.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Material {
    /// The floor slab.
    Floor,
    /// The ceiling slab.
    Ceiling,
    /// Walls, lintels and partitions.
    Wall,
    /// Open door leaves.
    Door,
    /// Desk tops and panels.
    Desk,
    /// Office chairs.
    Chair,
    /// Cabinets and shelves.
    Cabinet,
    /// Monitors, whiteboards and notice boards.
    Screen,
    /// Ceiling lights.
    Light,
    /// Plants, benches and other odds and ends.
    Decor,
}

/// An axis-aligned box of the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// Minimum corner, metres.
    pub min: [f64; 3],
    /// Maximum corner, metres.
    pub max: [f64; 3],
    /// What it is.
    pub material: Material,
}
