//! Proptest strategies that generate every valid message of both directions (any finite float bit pattern, any
//! integer, printable labels, ordered workspace corners).

use proptest::prelude::*;
use voxhap_protocol::{
    DeviceInfo, DeviceToHost, Enable, Fault, FaultCode, FaultFlags, ForceFlags, Heartbeat,
    HeartbeatReply, Hello, HostToDevice, Label, RateSet, RejectReason, Rejected, SetForce,
    SetStateRate, State, StatusFlags, Version,
};

/// Any finite f32, drawn from all bit patterns (subnormals, signed zeros, extremes included).
pub fn finite_f32() -> impl Strategy<Value = f32> {
    any::<u32>()
        .prop_map(f32::from_bits)
        .prop_filter("finite", |f| f.is_finite())
}

pub fn vec3() -> impl Strategy<Value = [f32; 3]> {
    [finite_f32(), finite_f32(), finite_f32()]
}

fn version() -> impl Strategy<Value = Version> {
    (any::<u8>(), any::<u8>()).prop_map(|(major, minor)| Version { major, minor })
}

fn label() -> impl Strategy<Value = Label> {
    "[ -~]{0,12}".prop_map(|text| Label::new(&text).expect("the regex only yields valid labels"))
}

pub fn host_to_device() -> impl Strategy<Value = HostToDevice> {
    prop_oneof![
        version().prop_map(|version| HostToDevice::Hello(Hello { version })),
        any::<u32>().prop_map(|watchdog_timeout_us| HostToDevice::Enable(Enable {
            watchdog_timeout_us
        })),
        Just(HostToDevice::Disable),
        (any::<u32>(), vec3(), any::<u16>()).prop_map(|(sequence, force_n, flags)| {
            HostToDevice::SetForce(SetForce {
                sequence,
                force_n,
                flags: ForceFlags(flags),
            })
        }),
        any::<u32>().prop_map(|counter| HostToDevice::Heartbeat(Heartbeat { counter })),
        Just(HostToDevice::ClearFault),
        any::<u16>()
            .prop_map(|state_rate_hz| HostToDevice::SetStateRate(SetStateRate { state_rate_hz })),
    ]
}

fn device_info() -> impl Strategy<Value = DeviceInfo> {
    (
        (
            version(),
            label(),
            label(),
            0u8..=6,
            0u8..=6,
            0u8..=16,
            any::<u8>(),
        ),
        (vec3(), vec3(), finite_f32(), finite_f32()),
    )
        .prop_map(
            |(
                (version, model, serial_number, position_dof, force_dof, button_count, rates),
                rest,
            )| {
                let (a, b, force, stiffness) = rest;
                DeviceInfo {
                    version,
                    model,
                    serial_number,
                    position_dof,
                    force_dof,
                    button_count,
                    supported_rates: RateSet(rates),
                    workspace_min_m: [a[0].min(b[0]), a[1].min(b[1]), a[2].min(b[2])],
                    workspace_max_m: [a[0].max(b[0]), a[1].max(b[1]), a[2].max(b[2])],
                    max_force_n: force.abs(),
                    max_stiffness_n_per_m: stiffness.abs(),
                }
            },
        )
}

fn state() -> impl Strategy<Value = State> {
    (any::<(u32, u64, u32, u16, u16, u16)>(), vec3(), vec3()).prop_map(
        |(
            (sequence, device_time_us, last_force_sequence, buttons, status, faults),
            position_m,
            velocity_m_per_s,
        )| {
            State {
                sequence,
                device_time_us,
                position_m,
                velocity_m_per_s,
                last_force_sequence,
                buttons,
                status: StatusFlags(status),
                faults: FaultFlags(faults),
            }
        },
    )
}

pub fn device_to_host() -> impl Strategy<Value = DeviceToHost> {
    prop_oneof![
        device_info().prop_map(DeviceToHost::DeviceInfo),
        state().prop_map(DeviceToHost::State),
        any::<(u32, u64, u16)>().prop_map(|(counter, device_time_us, status)| {
            DeviceToHost::Heartbeat(HeartbeatReply {
                counter,
                device_time_us,
                status: StatusFlags(status),
            })
        }),
        (0u8..=FaultCode::MAX, any::<u16>(), any::<u64>()).prop_map(
            |(code, active, device_time_us)| {
                DeviceToHost::Fault(Fault {
                    code: FaultCode(code),
                    active_faults: FaultFlags(active),
                    device_time_us,
                })
            }
        ),
        any::<(u8, u8)>().prop_map(|(message_type, reason)| {
            DeviceToHost::Rejected(Rejected {
                message_type,
                reason: RejectReason(reason),
            })
        }),
    ]
}
