//! One solve on a microcontroller's terms: no standard library, no allocator, the workspace in fixed arrays.
#![no_std]

use glam::DVec3;
use voxhap_solver::storage::Fixed;
use voxhap_solver::{Primitive, Problem, Solver, SolverConfig};

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {}
}

/// The proxy's height under a probe pressed 1 mm into a floor plane (0 when it certifies: the plane holds it
/// on the surface), or NaN when the solve is refused.
#[no_mangle]
pub extern "C" fn voxhap_no_std_floor_proxy_z() -> f64 {
    let Ok(floor) = Primitive::plane(DVec3::ZERO, DVec3::Z, 10.0) else {
        return f64::NAN;
    };
    let primitives = [floor];
    let mut solver: Solver<Fixed<8>> = Solver::new_in(SolverConfig::default(), 8);
    let problem = Problem {
        stiffness_n_per_m: 500.0,
        probe_m: DVec3::new(0.0, 0.0, -0.001),
        previous_proxy_m: None,
        primitives: &primitives,
    };
    match solver.solve(&problem) {
        Ok(solution) => solution.proxy_m.z,
        Err(_) => f64::NAN,
    }
}

/// One cycle of the device-side local loop (voxhap-local) on a session that has no model yet: the force it
/// returns (0 N without a model), or NaN if a component is not finite.
#[no_mangle]
pub extern "C" fn voxhap_no_std_local_step() -> f32 {
    use voxhap_local::{LocalLoop, LoopConfig};
    use voxhap_protocol::{DeviceInfo, DeviceSample, DeviceSession, Label, RateSet, PROTOCOL_VERSION};
    let info = DeviceInfo {
        version: PROTOCOL_VERSION,
        model: Label::new("no-std").unwrap_or_default(),
        serial_number: Label::new("0").unwrap_or_default(),
        position_dof: 3,
        force_dof: 3,
        button_count: 0,
        supported_rates: RateSet::default(),
        workspace_min_m: [-0.1; 3],
        workspace_max_m: [0.1; 3],
        max_force_n: 5.0,
        max_stiffness_n_per_m: 2000.0,
    };
    let mut session = DeviceSession::with_local_model(info);
    let mut local = LocalLoop::new(LoopConfig::default());
    let force = local.step(&mut session, 100, &DeviceSample::default());
    if force.iter().all(|f| f.is_finite()) {
        force[0] + force[1] + force[2]
    } else {
        f32::NAN
    }
}
