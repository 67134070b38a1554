use super::*;
use voxhap_core::status::OutputState;

fn snapshot(output_state: OutputState) -> Snapshot {
    Snapshot {
        probe_m: DVec3::new(0.01, -0.02, 0.03),
        probe_velocity_m_per_s: DVec3::new(0.1, 0.2, -0.3),
        rendered_force_n: DVec3::new(1.5, 0.0, -2.0),
        sent_force_n: DVec3::new(0.5, 0.0, -1.0),
        output_state,
        ..Snapshot::example()
    }
}

#[test]
fn faults_that_need_a_person_are_crtk_fault() {
    // CRTK "Robot API status": FAULT is a state the robot does not leave without the operator.
    assert_eq!(operating_state(Some(OutputState::Faulted)).0, "FAULT");
    assert_eq!(operating_state(Some(OutputState::EnableRefused)).0, "FAULT");
}

#[test]
fn every_output_state_maps_to_a_standard_crtk_state() {
    // crtk_msgs/OperatingState.msg: "Standard states include DISABLED, ENABLED, PAUSED and FAULT".
    for output in OutputState::ALL {
        let (name, _, _) = operating_state(Some(output));
        assert!(
            ["DISABLED", "ENABLED", "PAUSED", "FAULT"].contains(&name),
            "{output:?} -> {name}"
        );
    }
    assert_eq!(
        operating_state(Some(OutputState::Engaged)),
        ("ENABLED", true, false)
    );
    assert_eq!(
        operating_state(Some(OutputState::Disconnected)),
        ("DISABLED", false, false)
    );
    assert_eq!(operating_state(None), ("DISABLED", false, true));
}

#[test]
fn the_messages_carry_the_snapshot_in_si_units_in_the_world_frame() {
    let s = snapshot(OutputState::Engaged);
    let stamp = Time { sec: 7, nanosec: 9 };
    let m = messages(&s, stamp);
    let cp = m.measured_cp.unwrap();
    assert_eq!(cp.header.frame_id, "world");
    assert_eq!(cp.header.stamp, stamp);
    assert_eq!(
        (cp.pose.position.x, cp.pose.position.y, cp.pose.position.z),
        (0.01, -0.02, 0.03)
    );
    assert_eq!(cp.pose.orientation, Quaternion::IDENTITY);
    let cv = m.measured_cv.unwrap().twist;
    assert_eq!((cv.linear.x, cv.linear.y, cv.linear.z), (0.1, 0.2, -0.3));
    assert_eq!(cv.angular, Vector3::default());
    let cf = m.measured_cf.unwrap().wrench;
    assert_eq!((cf.force.x, cf.force.z), (1.5, -2.0));
    let setpoint = m.setpoint_cf.unwrap().wrench;
    assert_eq!((setpoint.force.x, setpoint.force.z), (0.5, -1.0));
    assert_eq!(setpoint.torque, Vector3::default());
    assert_eq!(m.operating_state.state, "ENABLED");
}

#[test]
fn a_non_finite_value_is_never_published() {
    let s = Snapshot {
        probe_m: DVec3::new(f64::NAN, 0.0, 0.0),
        sent_force_n: DVec3::new(0.0, f64::INFINITY, 0.0),
        ..snapshot(OutputState::Engaged)
    };
    let m = messages(&s, Time::default());
    assert!(m.measured_cp.is_none());
    assert!(m.setpoint_cf.is_none());
    assert!(m.measured_cv.is_some() && m.measured_cf.is_some());
}

#[test]
fn time_splits_nanoseconds_like_builtin_interfaces() {
    // builtin_interfaces/Time: int32 sec, uint32 nanosec (nanosec < 1e9).
    assert_eq!(
        Time::from_unix_ns(1_764_000_000_123_456_789),
        Time {
            sec: 1_764_000_000,
            nanosec: 123_456_789
        }
    );
    assert_eq!(Time::from_unix_ns(u64::MAX).sec, i32::MAX);
}

/// The safety pipeline faulted (a latched device fault, its force-off cause `device_fault`) is FAULT on
/// `operating_state` whatever output state the snapshot carries: CRTK "Robot API status", FAULT is a state
/// the robot does not leave without the operator.
#[test]
fn a_faulted_safety_pipeline_publishes_fault() {
    for output in OutputState::ALL {
        let s = Snapshot {
            truth: voxhap_api::TickTruth {
                force_off_cause: voxhap_api::ForceOffCause::DeviceFault,
                device_fault_bits: 0b10,
                ..voxhap_api::TickTruth::default()
            },
            ..snapshot(output)
        };
        let m = operating_state_message(Some(&s), Time::default());
        assert_eq!(m.state, "FAULT", "{output:?}");
        assert!(!m.is_busy);
    }
    // And the faulted output state alone, as the supervisor reports it.
    let m = operating_state_message(Some(&snapshot(OutputState::Faulted)), Time::default());
    assert_eq!(m.state, "FAULT");
}
