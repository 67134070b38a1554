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
