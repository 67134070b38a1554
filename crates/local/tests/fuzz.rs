//! The cargo-fuzz body of the `local_model` target (tests/fuzz_body.rs) under proptest, on arbitrary bytes and on
//! bytes shaped like a valid model with a few fields disturbed.

mod fuzz_body;

use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn fuzz_body_on_arbitrary_bytes(data in proptest::collection::vec(any::<u8>(), 0..700)) {
        fuzz_body::run(&data);
    }

    /// Bytes that decode: a small valid model (expiry 5000 us, stiffness 2000 N/m, limit 4 N, one plane, any
    /// passivity mode and damping code) with random slot data, so the loop runs on many decoded models rather
    /// than on refused ones.
    #[test]
    fn fuzz_body_on_model_shaped_bytes(slot in proptest::collection::vec(any::<u8>(), 12), probe in proptest::collection::vec(any::<u8>(), 0..150), passivity in 0u16..3, damping_code in 0u16..8) {
        let mut data = Vec::new();
        data.extend_from_slice(&1u32.to_le_bytes());
        data.extend_from_slice(&5000u16.to_le_bytes());
        // Slot 0 a plane; bits 9-10 the passivity mode, 11-13 its damping code.
        data.extend_from_slice(&(4u16 | passivity << 9 | damping_code << 11).to_le_bytes());
        data.extend_from_slice(&2000u16.to_le_bytes());
        data.extend_from_slice(&1000u16.to_le_bytes());
        data.extend_from_slice(&4000u16.to_le_bytes());
        data.extend_from_slice(&[0u8; 12]);
        data.extend_from_slice(&slot);
        data.extend_from_slice(&[0u8; 24]);
        data.extend_from_slice(&probe);
        fuzz_body::run(&data);
    }
}

/// The first crash the body found: an anchor finite in f64 but not in f32 (1e300 m) was built into a model the
/// encoder then refused. The builder now refuses it itself.
#[test]
fn an_anchor_beyond_f32_is_refused_by_the_builder() {
    let mut data = vec![0u8; 64];
    data[0..2].copy_from_slice(&5000u16.to_le_bytes());
    data[8..16].copy_from_slice(&2000f64.to_le_bytes());
    data[24..32].copy_from_slice(&4f64.to_le_bytes());
    data[32..40].copy_from_slice(&1e300f64.to_le_bytes());
    fuzz_body::run(&data);
    let params = voxhap_protocol::LocalModelParams {
        sequence: 1,
        expiry_us: 5000,
        stiffness_n_per_m: 2000.0,
        damping_n_s_per_m: 0.0,
        force_limit_n: 4.0,
        anchor_m: [1e300, 0.0, 0.0],
        passivity: voxhap_protocol::LocalPassivity::OFF,
    };
    let error = voxhap_protocol::build_local_model(&params, &[]).unwrap_err();
    assert!(error.to_string().contains("anchor_m.x"), "{error}");
}
