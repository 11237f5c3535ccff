//! Which vector unit of the CPU a hot loop is compiled for, chosen at run
//! time: the depth PNG decoder (`read/`) and the projection of a frame's keys
//! (`voxelize/`) both pick theirs here, so neither imports the other.

/// Which compilation of the projection runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VectorUnit {
    /// The build's own target features (baseline x86-64: SSE2).
    Baseline,
    /// x86-64 with AVX2 (and BMI1).
    Avx2,
    /// x86-64 with AVX-512 (F, VL, DQ, BW, CD; and POPCNT, BMI1).
    Avx512,
}

impl VectorUnit {
    /// Every unit this CPU can run, narrowest first.
    pub fn available() -> Vec<VectorUnit> {
        [VectorUnit::Baseline, VectorUnit::Avx2, VectorUnit::Avx512]
            .into_iter()
            .filter(|unit| unit.runs_here())
            .collect()
    }

    /// The widest unit this CPU can run.
    pub fn best() -> VectorUnit {
        Self::available().pop().unwrap_or(VectorUnit::Baseline)
    }

    /// Whether this CPU has the unit's features.
    pub(crate) fn runs_here(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        let has = |features: &[bool]| features.iter().all(|&f| f);
        match self {
            VectorUnit::Baseline => true,
            #[cfg(target_arch = "x86_64")]
            VectorUnit::Avx2 => has(&[
                is_x86_feature_detected!("avx2"),
                is_x86_feature_detected!("bmi1"),
            ]),
            #[cfg(target_arch = "x86_64")]
            VectorUnit::Avx512 => has(&[
                is_x86_feature_detected!("avx512f"),
                is_x86_feature_detected!("avx512vl"),
                is_x86_feature_detected!("avx512dq"),
                is_x86_feature_detected!("avx512bw"),
                is_x86_feature_detected!("avx512cd"),
                is_x86_feature_detected!("popcnt"),
                is_x86_feature_detected!("bmi1"),
            ]),
            #[cfg(not(target_arch = "x86_64"))]
            VectorUnit::Avx2 | VectorUnit::Avx512 => false,
        }
    }
}
