//! Offline dominating-set solvers of `G(mu)` (DESIGN section 2: `in-order`,
//! `greedy`, `exact`), the reference code's baselines, and class labels.
//!
//! Every solver returns frame indices in ascending order.

pub mod baselines;
pub mod exact;
pub mod greedy;
pub mod in_order;
pub mod labels;

pub use baselines::{cube, distance, every_nth};
pub use exact::{exact, ExactResult};
pub use greedy::greedy;
pub use in_order::{in_order, in_order_by};
pub use labels::{is_dominating, labels};
