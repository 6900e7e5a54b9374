//! Evaluation tools: the measurement oracle ([`oracle`]) and its record ([`record`]), the policy comparison
//! ([`compare`]), the trade-off study of characterization settings
//! ([`tradeoff`]), the failure study ([`failure_study`]), charts ([`chart`]) and pictures of the classes
//! ([`render`]).

pub mod chart;
pub mod compare;
pub mod e2e;
pub mod failure_study;
pub mod fit;
pub mod oracle;
pub mod proxy;
pub mod record;
pub mod render;
pub mod scene;
pub mod tradeoff;

pub use oracle::{evaluate_scene, EvalError, Measurement, OracleConfig, Rebuild, SceneEvaluation, StructureResult};
pub use record::{OracleRecord, StructureRecord};
pub use scene::load_scene;

#[cfg(test)]
mod tests;
