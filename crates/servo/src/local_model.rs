//! The tick's local model for a device that renders contact itself (protocol/SPEC.md section 10): the
//! primitives the tick solved with, the coupling and the proxy, as a [`LocalOffer`] the supervisor hands to a
//! capable driver (`voxhap_device::local_offer`).
//!
//! Where it sits: [`crate::runner`] calls [`offer`] every tick after the solve; the supervisor uses the offer
//! only for a device that announced the capability, and only while the force it would send is valid. Fixed-size
//! and allocation-free.

use crate::passivity::{PassivityMode, PassivitySettings};
use glam::DVec3;
use voxhap_core::haptics::tick::TickStatus;
use voxhap_device::local_offer::{LocalOffer, PassivityOffer};
use voxhap_protocol::{LocalKind, LocalPassivityMode, SiPrimitive};
use voxhap_solver::primitive::PrimitiveKind;
use voxhap_solver::Primitive;

/// The offer for a tick: coupling `k` and `b`, the host's proxy as the anchor, and the tick's primitives in
/// the order the modes emitted them (the driver keeps the summed directed forces and the nearest three).
pub fn offer(
    primitives: &[Primitive],
    stiffness_n_per_m: f64,
    damping_n_s_per_m: f64,
    proxy_m: DVec3,
) -> LocalOffer {
    let mut offer = LocalOffer::new(stiffness_n_per_m, damping_n_s_per_m, proxy_m);
    for p in primitives {
        offer.push(SiPrimitive {
            kind: match p.kind() {
                PrimitiveKind::Directed => LocalKind::Directed,
                PrimitiveKind::Point => LocalKind::Point,
                PrimitiveKind::Line => LocalKind::Line,
                PrimitiveKind::Plane => LocalKind::Plane,
            },
            position_m: p.position_m().to_array(),
            direction: p.direction().to_array(),
            strength_n: p.strength_n(),
        });
    }
    offer
}

/// What [`force_valid`] decides from, each by its name (so that a call cannot swap two of them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ForceChecks {
    /// The tick rendered from a fresh state.
    pub state_fresh: bool,
    /// The tick's status: a tick that rejected its input has no valid force.
    pub status: TickStatus,
    /// The force was finite (not replaced for being non-finite).
    pub force_finite: bool,
    /// The force was computed within its budget.
    pub on_budget: bool,
}

/// Whether the tick's force is valid, `serve`'s rule for sending a capable device the tick's local model
/// rather than a set-force ([`crate::runner`], which hands it to the supervisor as `TickInput::force_valid`;
/// `voxhap sim`'s [`crate::sim::runner`] decides with it too): the tick rendered from a fresh state, did not
/// reject its input, its force was finite and it was computed within its budget ([`ForceChecks`]).
pub fn force_valid(checks: ForceChecks) -> bool {
    checks.state_fresh
        && checks.status != TickStatus::InputRejected
        && checks.force_finite
        && checks.on_budget
}

/// What a capable device's own passivity observer and controller run (protocol/SPEC.md section 10.5 step 4b):
/// the host's mode and the scene's `[passivity] max_damping_n_s_per_m` (scaled into the device frame with the
/// coupling, then sent as the largest of the wire's steps 1.25 × 2^c N s/m, c = 0..7, not above it).
pub fn passivity_request(mode: PassivityMode, settings: &PassivitySettings) -> PassivityOffer {
    let mode = match mode {
        PassivityMode::Off => LocalPassivityMode::Off,
        PassivityMode::Observe => LocalPassivityMode::Observe,
        PassivityMode::Control => LocalPassivityMode::Control,
    };
    PassivityOffer {
        mode,
        max_damping_n_s_per_m: settings.max_damping_n_s_per_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use voxhap_device::local_offer::MAX_OFFER_PRIMITIVES;

    #[test]
    fn every_kind_travels_with_its_fields_and_a_full_offer_says_so() {
        let plane = Primitive::plane(DVec3::new(0.0, 0.0, 0.01), DVec3::Z, 3.0).unwrap();
        let point = Primitive::point(DVec3::new(0.001, 0.0, 0.0), 0.5).unwrap();
        let directed = Primitive::directed(DVec3::new(0.0, 2.0, 0.0), 0.25).unwrap();
        let offer = offer(&[plane, point, directed], 800.0, 0.5, DVec3::ONE);
        assert_eq!(offer.stiffness_n_per_m, 800.0);
        assert_eq!(offer.damping_n_s_per_m, 0.5);
        assert_eq!(offer.anchor_m, DVec3::ONE);
        let got = offer.primitives();
        assert_eq!(got.len(), 3);
        assert_eq!(got[0].kind, LocalKind::Plane);
        assert_eq!(got[0].position_m, [0.0, 0.0, 0.01]);
        assert_eq!(got[0].direction, [0.0, 0.0, 1.0]);
        assert_eq!(got[0].strength_n, 3.0);
        assert_eq!(got[1].kind, LocalKind::Point);
        assert_eq!(got[2].kind, LocalKind::Directed);
        // The directed force's direction is normalised by the primitive (unit y).
        assert_eq!(got[2].direction, [0.0, 1.0, 0.0]);
        assert!(!offer.truncated());

        let many = vec![point; MAX_OFFER_PRIMITIVES + 1];
        let full = super::offer(&many, 800.0, 0.0, DVec3::ZERO);
        assert_eq!(full.primitives().len(), MAX_OFFER_PRIMITIVES);
        assert!(full.truncated());
    }

    /// The device's observer and controller (voxhap-local, written apart for `no_std`) against the host's
    /// (crate::passivity::controller) at latency 0 on one input sequence: a spring of 5 000 N/m on a probe
    /// circling at 40 Hz, 0.1 by 0.3 mm, sampled at 10 kHz (about 0.1 uJ generated a cycle, so the 1 uJ
    /// threshold matters), its force clamped to 1 N (so the share varies), the
    /// reference `share^2 k/2 |stretch|^2` with last cycle's share, as the serve runner forms it. Every force
    /// and total agree to rounding. Checked to fail with the device's threshold doubled (its controller then
    /// acts in fewer cycles).
    #[test]
    fn the_device_controller_matches_the_hosts_on_one_sequence() {
        use crate::energy::SentShare;
        use crate::passivity::PassivityController;
        use voxhap_local::DevicePassivity;
        let (k, dt, limit) = (5000.0, 1e-4, 1.0);
        let settings = PassivitySettings::default();
        let request = voxhap_protocol::LocalPassivity::new(LocalPassivityMode::Control, 20.0);
        let mut host = PassivityController::new(PassivityMode::Control, &settings, 0);
        let mut device = DevicePassivity::default();
        let mut share = SentShare::NOTHING;
        let proxy = DVec3::new(0.0, 0.0, 0.0);
        let mut dissipating = 0;
        for i in 0..4000 {
            let t = i as f64 * dt;
            let w = 2.0 * std::f64::consts::PI * 40.0;
            // An ellipse around the proxy: the sampled spring generates `k dp^2 / 2` a cycle.
            let probe = DVec3::new(0.0001 * (w * t).cos(), 0.0, -0.0003 * (w * t).sin());
            let velocity = DVec3::new(
                -0.0001 * w * (w * t).sin(),
                0.0,
                -0.0003 * w * (w * t).cos(),
            );
            let stretch = proxy - probe;
            let reference = share.spring_energy_j(k, stretch);
            let host_control = host.observe_and_control(probe, velocity, reference, dt);
            let host_control = if share.fraction() > 0.0 {
                host_control
            } else {
                DVec3::ZERO
            };
            let device_control =
                device.observe_and_control(request, k, probe, velocity, stretch, dt);
            assert!(
                (host_control - device_control).length() <= 1e-12,
                "cycle {i}: host {host_control}, device {device_control}"
            );
            let asked = k * stretch + host_control;
            let sent = if asked.length() > limit {
                asked * (limit / asked.length())
            } else {
                asked
            };
            host.sent(asked, sent);
            device.applied(request, asked, sent, DVec3::ZERO);
            share = SentShare::of(sent, asked);
            dissipating += usize::from(device_control != DVec3::ZERO);
            let (h, d) = (host.totals(), device.totals());
            assert!(
                (h.generated_j - d.generated_j).abs() <= 1e-12
                    && (h.excess_j - d.excess_j).abs() <= 1e-12
                    && (h.dissipated_j - d.dissipated_j).abs() <= 1e-12
                    && h.active_ticks == d.active_cycles,
                "cycle {i}: host {h:?}, device {d:?}"
            );
        }
        assert!(
            dissipating > 100,
            "the controller acted in {dissipating} cycles"
        );
    }

    /// The scene's mode travels as is; its most damping goes into the device frame with the coupling and onto
    /// the wire as the largest step 1.25 x 2^c N s/m not above it (SPEC 10.2): the default 20 N s/m is step 4
    /// exactly, 1000 N s/m (the largest a scene takes) the top step 160, 3 N s/m the step 2.5, 0.5 N s/m the
    /// bottom step 1.25; 20 N s/m through a mapping of scale 0.5 is 10 N s/m, step 3.
    #[test]
    fn the_scenes_passivity_becomes_the_devices_request() {
        let settings = PassivitySettings::default();
        let sent = |mode, max_damping, scale: f64| {
            let settings = PassivitySettings {
                max_damping_n_s_per_m: max_damping,
                ..settings
            };
            let offer = super::offer(&[], 800.0, 0.5, DVec3::ZERO)
                .with_passivity(passivity_request(mode, &settings))
                .mapped(|p| p, |d| d, scale);
            offer.params(3.0, 5.0).passivity
        };
        let control = sent(PassivityMode::Control, 20.0, 1.0);
        assert_eq!(control.mode, LocalPassivityMode::Control);
        assert_eq!(control.max_damping_n_s_per_m(), 20.0);
        assert_eq!(
            sent(PassivityMode::Off, 20.0, 1.0).mode,
            LocalPassivityMode::Off
        );
        for (asked, scale, got) in [
            (1000.0, 1.0, 160.0),
            (3.0, 1.0, 2.5),
            (0.5, 1.0, 1.25),
            (20.0, 0.5, 10.0),
        ] {
            let request = sent(PassivityMode::Observe, asked, scale);
            assert_eq!(request.mode, LocalPassivityMode::Observe);
            assert_eq!(request.max_damping_n_s_per_m(), got, "{asked} x {scale}");
        }
    }
}
