//! The offline yardstick: the exact overlap graph ([`graph`]), the
//! dominating-set solvers and baselines ([`solve`]) and the metrics of a
//! database ([`metrics`]).

pub mod graph;
pub mod metrics;
pub mod solve;
