//! The settings grid: one knob at a time around the reference computation.

use super::*;

/// One point of the settings grid: a backend and the characterization parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    /// Which backend runs it.
    pub backend: Backend,
    /// The parameters (`keep_per_triangle` is always off).
    pub params: Params,
}

impl Setting {
    /// The reference: the rayon CPU backend with the default parameters (every triangle, 30-bit codes, Doane).
    pub fn reference() -> Setting {
        Setting { backend: Backend::Cpu, params: Params::default() }
    }

    /// A short label, `backend/bits/rule/1:stride`, e.g. `cpu/30/doane/1:16`.
    pub fn label(&self) -> String {
        format!(
            "{}/{}/{}/1:{}",
            self.backend.name(),
            self.params.morton_bits.total(),
            self.params.class_rule.name(),
            self.params.sample_stride
        )
    }

    /// Whether the two settings compute the same numbers (they may differ in backend only).
    pub fn same_parameters(&self, o: &Setting) -> bool {
        self.params == o.params
    }
}

/// The knobs to sweep. [`GridSpec::settings`] varies one knob at a time around the reference.
#[derive(Clone, Debug, PartialEq)]
pub struct GridSpec {
    /// Backends; the first is the reference backend for the bit-depth and class-rule variations.
    pub backends: Vec<Backend>,
    /// Sample strides (1 = every triangle, 2 = half, ...).
    pub strides: Vec<u32>,
    /// Bit depths; the default (30) is always included.
    pub bits: Vec<MortonBits>,
    /// Class rules; Doane is always included.
    pub rules: Vec<ClassRule>,
}

impl Default for GridSpec {
    /// Every backend (CPU first), strides 1 to 256 in powers of two, 30 and 63 bits, Doane, Sturges, square root
    /// and fixed 8, 16, 32, 64 classes.
    fn default() -> Self {
        GridSpec {
            backends: vec![Backend::Cpu, Backend::Vulkan, Backend::Naive],
            strides: (0..=8).map(|i| 1u32 << i).collect(),
            bits: vec![MortonBits::Bits30, MortonBits::Bits63],
            rules: vec![
                ClassRule::Doane,
                ClassRule::Sturges,
                ClassRule::Sqrt,
                ClassRule::Fixed(8),
                ClassRule::Fixed(16),
                ClassRule::Fixed(32),
                ClassRule::Fixed(64),
            ],
        }
    }
}

impl GridSpec {
    /// The settings, one knob at a time: every backend at every stride (30 bits, Doane); on the first backend,
    /// every other bit depth at every stride, and every other rule with every triangle. No duplicates; the first
    /// setting is the reference when the first backend is the CPU and stride 1 is in the list.
    pub fn settings(&self) -> Vec<Setting> {
        let mut out: Vec<Setting> = Vec::new();
        let mut push = |s: Setting| {
            if !out.contains(&s) {
                out.push(s);
            }
        };
        let base = Params::default();
        let mut strides = self.strides.clone();
        strides.retain(|&s| s >= 1);
        if !strides.contains(&1) {
            strides.insert(0, 1);
        }
        for &backend in &self.backends {
            for &s in &strides {
                push(Setting { backend, params: Params { sample_stride: s, ..base.clone() } });
            }
        }
        let Some(&first) = self.backends.first() else {
            return out;
        };
        for &bits in self.bits.iter().filter(|&&b| b != base.morton_bits) {
            for &s in &strides {
                push(Setting {
                    backend: first,
                    params: Params { morton_bits: bits, sample_stride: s, ..base.clone() },
                });
            }
        }
        for &rule in self.rules.iter().filter(|&&r| r != base.class_rule) {
            push(Setting { backend: first, params: Params { class_rule: rule, ..base.clone() } });
        }
        out
    }
}
