//! What `placedb bench` measures beside its timing table: instructions per
//! pixel on the QEMU board ([`pixel_cost`]) and one frame against a small and
//! a large database ([`db_scaling`]).

pub mod db_scaling;
pub mod pixel_cost;
