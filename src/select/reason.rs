//! Why a structure was chosen: one typed line per finding, each with the sentence a person reads.

use super::{Level, Structure};

/// What a reason is about, with the figures a program would act on; the sentence is in [`Reason::text`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ReasonKind {
    /// A rule of the thesis policy fired or fell through (distribution, kind of scene, concentration, spread).
    Rule,
    /// The structure a model chose, and the model.
    Choice {
        /// The structure chosen.
        structure: Structure,
    },
    /// How far the runner-up stands from the choice.
    Margin {
        /// The next structure the policy could have chosen.
        runner_up: Structure,
        /// Its predicted total over the chosen structure's.
        ratio: f64,
        /// The ratio lies within the two predictions' fit errors combined.
        close_call: bool,
    },
    /// One candidate's predicted build, trace and total.
    Prediction {
        /// The candidate.
        structure: Structure,
        /// Its predicted total in milliseconds.
        total_ms: f64,
    },
    /// A structure left out before choosing, its bound over the budget.
    Excluded,
    /// The level of the ladder of inquiry that decided.
    Decided {
        /// The level.
        level: Level,
    },
    /// A level of the ladder: what it found, or why it was not climbed.
    Inquiry {
        /// The level.
        level: Level,
        /// It was climbed.
        taken: bool,
    },
    /// The view the rays come from.
    View,
    /// The workload the choice is for: how its rays per frame were counted or estimated.
    Workload,
    /// The per-frame plan of an animation (rebuilds, refits).
    Plan,
    /// The policy asked could not decide, and another did.
    Fallback,
    /// The driver's acceleration structures: a prediction, the flags chosen, or the comparison with the project's.
    Driver,
}

/// One reason for a selection: its kind and its sentence. It displays, and serializes, as the sentence.
#[derive(Clone, Debug, PartialEq)]
pub struct Reason {
    /// What it is about.
    pub kind: ReasonKind,
    /// The sentence, with the numbers behind it.
    pub text: String,
}

impl Reason {
    /// A reason of `kind` that says `text`.
    pub fn new(kind: ReasonKind, text: impl Into<String>) -> Self {
        Reason { kind, text: text.into() }
    }
}

impl std::fmt::Display for Reason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.text)
    }
}

impl AsRef<str> for Reason {
    fn as_ref(&self) -> &str {
        &self.text
    }
}

impl serde::Serialize for Reason {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.text)
    }
}

/// The sentences of `reasons` joined by `sep`.
pub(crate) fn join(reasons: &[Reason], sep: &str) -> String {
    reasons.iter().map(|r| r.text.as_str()).collect::<Vec<_>>().join(sep)
}
