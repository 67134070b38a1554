//! Haptic rendering: primitives, the exact proxy solver and the paper's baselines.
