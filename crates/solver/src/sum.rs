//! Running sums of 3-vectors: compensated (Neumaier) where the certificate's bounds depend on it, plain where
//! speed matters more.

use glam::DVec3;

/// Neumaier's compensated sum of 3-vectors: the error is about 2 eps of the result plus n eps^2 of the sum of
/// magnitudes, instead of n eps of the sum of magnitudes. Each step's rounding error is computed exactly (by
/// Knuth's TwoSum, branch-free), so the sums, and the bounds built on them, are those of Neumaier's algorithm.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct CompensatedSum {
    sum: DVec3,
    compensation: DVec3,
}

/// A running sum of 3-vectors: [`CompensatedSum`] or [`PlainSum`] (the primal Newton passes pick one).
pub(crate) trait GradientSum: Default {
    fn add(&mut self, v: DVec3);
    fn value(&self) -> DVec3;
}

/// A plain running sum (error up to n eps of the sum of magnitudes).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PlainSum(DVec3);

impl GradientSum for PlainSum {
    #[inline]
    fn add(&mut self, v: DVec3) {
        self.0 += v;
    }

    #[inline]
    fn value(&self) -> DVec3 {
        self.0
    }
}

impl GradientSum for CompensatedSum {
    #[inline]
    fn add(&mut self, v: DVec3) {
        CompensatedSum::add(self, v);
    }

    #[inline]
    fn value(&self) -> DVec3 {
        CompensatedSum::value(self)
    }
}

impl CompensatedSum {
    #[inline]
    pub(crate) fn add(&mut self, v: DVec3) {
        // Knuth's TwoSum: `lost` is the rounding error of `t` exactly (as in Neumaier's branch on the larger
        // magnitude, which gives the same value), in six operations per coordinate and no comparison.
        let t = self.sum + v;
        let v_part = t - self.sum;
        let sum_part = t - v_part;
        let lost = (self.sum - sum_part) + (v - v_part);
        self.compensation += lost;
        self.sum = t;
    }

    pub(crate) fn value(&self) -> DVec3 {
        self.sum + self.compensation
    }
}
