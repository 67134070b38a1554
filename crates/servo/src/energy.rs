//! The energy ledger: every tick, from what was sent and what the device reported, how much energy the
//! renderer put into the hand, and whether contact has become a limit cycle.
//!
//! Where it sits: after a tick's force is known and before the next probe position is read: in the sim
//! runner (`super::sim::runner`, the force rendered is the force sent) and in the servo tick of `serve`
//! (`super::runner`, booked from the position the device reported and the force the safety pipeline sent,
//! every device; a tick without a device state is a gap). Allocation-free, a few additions per tick; the
//! totals reach the trace columns, the snapshot and [`EnergyStats`] (`/api/stats`, the run summary).
//!
//! In `serve` the device damping `b` below is the damping the device's declared stiffness implies
//! (`CouplingCaps::device_damping_n_s_per_m`, docs/safety.md); in a sim it is the arm's `[arm]` damping.
//!
//! The books (SI, joules; `x_n` the reported probe position at tick `n`, `F_n` the force sent at tick `n`
//! and held until the next, as a device's amplifier does):
//!
//! - **work on the probe** `W = sum F_n . (x_{n+1} - x_n)`: the work the sent force did on the hand. Under a
//!   zero-order hold and without latency this is exact (the force is constant over the step).
//! - **coupling energy** `E_c = k/2 |proxy - probe|^2`: what the coupling spring holds now.
//! - **generated** `G = W + E_c - E_c(0)`: what the renderer gave beyond what it was given. A continuous
//!   spring keeps `G = 0`; the sampled one generates (its force lags the motion by about `T/2`), which is what
//!   Colgate and Schenkel's bound weighs against the device's damping.
//! - **active work** `A = sum F_active,n . (x_{n+1} - x_n)`, `F_active` the force of the directed-force modes
//!   (`vector_force`, `gradient_force`), which are meant to do work: it is split out of `G`.
//! - **device dissipation** `D = sum b |x_{n+1} - x_n|^2 / T`: what the device's own damping `b` took at
//!   least (the mean speed over a step squared never exceeds the mean of the squared speed).
//! - **net generated** `N = G - A - D`: energy the coupling pumped into the arm beyond what the arm's damping
//!   could take, when the coupling is the only source. Where the hand also does work (it pushes, it drags)
//!   `D` includes the dissipation of the hand's energy, so `N` under-reports: a bouncing contact under a
//!   pushing hand can keep `N` negative. Contact limit cycles are caught by the oscillation test instead.
//!
//! Under a local model (`crate::device::LocalDevice`) each device cycle is booked on its own: `F_n` is the force
//! the device applied in the cycle, `F_active` the directed force it applied (the share of the model's directed
//! force its clamp, ramp and slew limit let out) and `E_c` the share of the reaction's spring only, so that the
//! split is exact for the loop's composition (the module docs there derive it).
//!
//! `--fail-on active` is met when `N` rose by more than [`ACTIVE_TOLERANCE_J`] over any window (the largest
//! rise `N(t) - min_{s <= t} N(s)`). `--fail-on oscillation` is met by a contact limit cycle: at least
//! [`OSCILLATION_CYCLES`] contacts in a row, each begun within [`OSCILLATION_GAP_S`] of the previous one's end and
//! with a peak force at least [`UNDECAYING_RATIO`] of the previous one's, that do not decay: over the last
//! [`OSCILLATION_CYCLES`] contacts, neither their peak forces nor the probe's speeds into them (over the step
//! before each contact) decay, a measure decaying when its largest over the later half of the window is below
//! [`UNDECAYING_RATIO`] of its largest over the earlier half. A bounce whose measure decays geometrically by `r`
//! per contact is told apart when `r^5 < 0.95` (`r` < 0.99: it halves within 70 contacts), though each contact
//! passes the contact-to-contact test. The speed, as well as the force: under a steady push the peak force of a
//! decaying bounce tends to twice the static force, not to zero, while the speed into each contact (the
//! bounce's energy) falls to zero.

use glam::DVec3;
use std::sync::atomic::{AtomicU64, Ordering};
use voxhap_api::{EnergyReport, TickEnergy};

/// Rise of the net generated energy that counts as active (J): 0.1 mJ.
pub const ACTIVE_TOLERANCE_J: f64 = 1e-4;
/// Contacts in a row that make a limit cycle.
pub const OSCILLATION_CYCLES: u32 = 10;
/// Longest gap between the end of one contact and the start of the next in a limit cycle (s).
pub const OSCILLATION_GAP_S: f64 = 0.1;
/// A contact whose peak force is at least this fraction of the previous one's is undecaying; a window of
/// [`OSCILLATION_CYCLES`] such contacts is undecaying when the largest peak force of its later half is at least
/// this fraction of the largest of its earlier half, and so is the largest speed into a contact.
pub const UNDECAYING_RATIO: f64 = 0.95;
/// A coupling force above this counts as contact (N).
pub const CONTACT_FORCE_N: f64 = 1e-3;

/// How much of the force a tick rendered the safety pipeline sent: `|F_sent| / |F_rendered|`, at most 1 (0
/// while nothing is sent, before engaging; between 0 and 1 while it ramps in or limits); 1 when nothing was
/// rendered. `F_rendered` is the force handed to the pipeline (spring, damping, passivity controller).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SentShare(f64);

impl SentShare {
    /// Nothing sent (before the first exchange).
    pub const NOTHING: SentShare = SentShare(0.0);
    /// All of it sent (the simulated arm's set-force path).
    pub const ALL: SentShare = SentShare(1.0);

    /// The share of `rendered_n` that went out as `sent_n`.
    pub fn of(sent_n: DVec3, rendered_n: DVec3) -> Self {
        let rendered = rendered_n.length();
        SentShare(if rendered > 0.0 {
            (sent_n.length() / rendered).min(1.0)
        } else {
            1.0
        })
    }

    /// The share, from 0 to 1.
    pub fn fraction(self) -> f64 {
        self.0
    }

    /// The energy the sent force can give back: the coupling spring's energy `k/2 |stretch|^2` scaled by the
    /// square of the share, which is `|F_sent|^2 / 2k` for a pure spring (`F_sent = share k stretch`). The
    /// ledger books this as the coupling energy and the passivity observer follows it as its reference:
    /// booking the whole virtual spring would count a probe pressed deeper before engaging as energy
    /// generated.
    pub fn spring_energy_j(self, k_n_per_m: f64, stretch_m: DVec3) -> f64 {
        0.5 * k_n_per_m * stretch_m.length_squared() * self.0 * self.0
    }

    /// [`SentShare::spring_energy_j`] of the coupling without the directed forces' part: the proxy solve
    /// minimises `k/2 |x - p - d/k|^2 + ...`, so the spring that gives energy back is stretched by
    /// `stretch - d/k`, while `d` (`directed_n`, the directed-force modes' force) does intended work, booked as
    /// active. The ledger books this as the coupling energy and the passivity observer follows it.
    pub fn reaction_energy_j(self, k_n_per_m: f64, stretch_m: DVec3, directed_n: DVec3) -> f64 {
        let directed_stretch_m = if k_n_per_m > 0.0 {
            directed_n / k_n_per_m
        } else {
            DVec3::ZERO
        };
        self.spring_energy_j(k_n_per_m, stretch_m - directed_stretch_m)
    }
}

/// Defines [`EnergyTotals`] and its atomic mirror [`EnergyStats`] from one field list, so a new total is
/// stored and loaded for `/api/stats` as soon as it is declared.
macro_rules! energy_totals {
    ($($(#[doc = $doc:literal])* $field:ident: $ty:ty,)*) => {
        /// The ledger's running totals (module docs).
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        pub struct EnergyTotals {
            $($(#[doc = $doc])* pub $field: $ty,)*
        }

        /// The ledger's totals as atomics, one per [`EnergyTotals`] field: the servo thread stores them every
        /// tick (a few relaxed stores, no allocation), `/api/stats` and the run summary read them.
        #[derive(Debug, Default)]
        pub struct EnergyStats {
            $($field: AtomicU64,)*
        }

        impl EnergyStats {
            /// Stores `totals` (servo thread).
            pub fn store(&self, totals: &EnergyTotals) {
                $(self.$field.store(AtomicBits::to_bits(totals.$field), Ordering::Relaxed);)*
            }

            /// The totals last stored.
            pub fn load(&self) -> EnergyTotals {
                EnergyTotals {
                    $($field: AtomicBits::from_bits(self.$field.load(Ordering::Relaxed)),)*
                }
            }
        }
    };
}

energy_totals! {
    /// Work the sent force did on the probe (J).
    work_on_probe_j: f64,
    /// The coupling spring's energy now (J).
    coupling_energy_j: f64,
    /// Energy generated by the renderer (J).
    generated_j: f64,
    /// Work of the directed-force modes on the probe (J).
    active_work_j: f64,
    /// The least the device's own damping dissipated (J).
    device_dissipation_j: f64,
    /// Generated, less active work and device dissipation (J).
    net_generated_j: f64,
    /// The largest rise of `net_generated_j` over any window (J).
    largest_rise_j: f64,
    /// Contacts begun.
    contacts: u64,
    /// The longest run of undecaying contacts in quick succession.
    longest_cycle_run: u32,
    /// Work the passivity controller's damping took from the probe (J; crate::passivity).
    passivity_dissipated_j: f64,
}

/// A total's value as the 64 bits an [`AtomicU64`] holds, and back (exact for every value).
trait AtomicBits: Copy {
    fn to_bits(self) -> u64;
    fn from_bits(bits: u64) -> Self;
}

impl AtomicBits for f64 {
    fn to_bits(self) -> u64 {
        f64::to_bits(self)
    }
    fn from_bits(bits: u64) -> Self {
        f64::from_bits(bits)
    }
}

impl AtomicBits for u64 {
    fn to_bits(self) -> u64 {
        self
    }
    fn from_bits(bits: u64) -> Self {
        bits
    }
}

impl AtomicBits for u32 {
    fn to_bits(self) -> u64 {
        u64::from(self)
    }
    fn from_bits(bits: u64) -> Self {
        // Only ever a stored u32.
        bits as u32
    }
}

/// The energy ledger of one run.
#[derive(Debug, Clone)]
pub struct EnergyLedger {
    device_damping_n_s_per_m: f64,
    totals: EnergyTotals,
    initial_coupling_j: Option<f64>,
    last: Option<(DVec3, DVec3, DVec3)>,
    lowest_net_j: f64,
    in_contact: bool,
    contact_peak_n: f64,
    previous_peak_n: f64,
    last_contact_end_s: f64,
    cycle_run: u32,
    /// The speed of the probe over the step into the current contact (m/s).
    contact_approach_m_per_s: f64,
    /// The peak forces of the last [`OSCILLATION_CYCLES`] contacts, oldest first (N).
    peaks_n: [f64; OSCILLATION_CYCLES as usize],
    /// The approach speeds of the same contacts, oldest first (m/s).
    approaches_m_per_s: [f64; OSCILLATION_CYCLES as usize],
}

impl EnergyLedger {
    /// A ledger for a device whose own damping is `device_damping_n_s_per_m`.
    pub fn new(device_damping_n_s_per_m: f64) -> Self {
        EnergyLedger {
            device_damping_n_s_per_m,
            totals: EnergyTotals::default(),
            initial_coupling_j: None,
            last: None,
            lowest_net_j: 0.0,
            in_contact: false,
            contact_peak_n: 0.0,
            previous_peak_n: 0.0,
            last_contact_end_s: f64::NEG_INFINITY,
            cycle_run: 0,
            contact_approach_m_per_s: 0.0,
            peaks_n: [0.0; OSCILLATION_CYCLES as usize],
            approaches_m_per_s: [0.0; OSCILLATION_CYCLES as usize],
        }
    }

    /// Books tick `n` at `t_s` (period `dt_s`): the reported probe position, the force sent this tick, the
    /// directed-force modes' part of it, and the coupling spring's energy and force magnitude this tick.
    pub fn record(
        &mut self,
        t_s: f64,
        dt_s: f64,
        probe_m: DVec3,
        sent_force_n: DVec3,
        active_force_n: DVec3,
        coupling_energy_j: f64,
    ) -> EnergyTotals {
        let t = &mut self.totals;
        let approach_m_per_s = self
            .last
            .map_or(0.0, |(x, _, _)| (probe_m - x).length() / dt_s);
        if let Some((x, f, active)) = self.last {
            let dx = probe_m - x;
            t.work_on_probe_j += f.dot(dx);
            t.active_work_j += active.dot(dx);
            t.device_dissipation_j += self.device_damping_n_s_per_m * dx.length_squared() / dt_s;
        }
        let initial = *self.initial_coupling_j.get_or_insert(coupling_energy_j);
        t.coupling_energy_j = coupling_energy_j;
        t.generated_j = t.work_on_probe_j + coupling_energy_j - initial;
        t.net_generated_j = t.generated_j - t.active_work_j - t.device_dissipation_j;
        self.lowest_net_j = self.lowest_net_j.min(t.net_generated_j);
        t.largest_rise_j = t.largest_rise_j.max(t.net_generated_j - self.lowest_net_j);
        self.last = Some((probe_m, sent_force_n, active_force_n));

        let force_n = sent_force_n.length();
        let touching = force_n > CONTACT_FORCE_N;
        if touching && !self.in_contact {
            t.contacts += 1;
            let quick = t_s - self.last_contact_end_s <= OSCILLATION_GAP_S;
            self.cycle_run = if quick { self.cycle_run + 1 } else { 1 };
            self.contact_peak_n = 0.0;
            self.contact_approach_m_per_s = approach_m_per_s;
        }
        if touching {
            self.contact_peak_n = self.contact_peak_n.max(force_n);
        }
        if !touching && self.in_contact {
            if self.contact_peak_n < UNDECAYING_RATIO * self.previous_peak_n {
                self.cycle_run = 1;
            }
            self.previous_peak_n = self.contact_peak_n;
            push(&mut self.peaks_n, self.contact_peak_n);
            push(&mut self.approaches_m_per_s, self.contact_approach_m_per_s);
            let decays =
                envelope_decays(&self.peaks_n) || envelope_decays(&self.approaches_m_per_s);
            if self.cycle_run >= OSCILLATION_CYCLES && decays {
                // The window slides on: its latest contacts may yet begin an undecaying one.
                self.cycle_run = OSCILLATION_CYCLES - 1;
            }
            self.last_contact_end_s = t_s;
            t.longest_cycle_run = t.longest_cycle_run.max(self.cycle_run);
        }
        self.in_contact = touching;
        *t
    }

    /// Books what the passivity controller has dissipated so far (J; crate::passivity); part of every
    /// totals returned after.
    pub fn book_passivity(&mut self, dissipated_j: f64) {
        self.totals.passivity_dissipated_j = dissipated_j;
    }

    /// The totals so far.
    pub fn totals(&self) -> EnergyTotals {
        self.totals
    }

    /// The device's own damping changed (a reconnected device declares another).
    pub fn set_device_damping(&mut self, device_damping_n_s_per_m: f64) {
        self.device_damping_n_s_per_m = device_damping_n_s_per_m;
    }

    /// A tick without a probe position to book (no device, no state yet): the next booked tick starts a new
    /// step instead of spanning the gap (a reconnected device's position may have jumped).
    pub fn gap(&mut self) {
        self.last = None;
    }
}

/// Appends `value` to a window, dropping its oldest.
fn push(window: &mut [f64], value: f64) {
    window.rotate_left(1);
    if let Some(last) = window.last_mut() {
        *last = value;
    }
}

/// Whether a measure of a window of contacts (oldest first) decays: the largest of the later half is below
/// [`UNDECAYING_RATIO`] of the largest of the earlier half (the largest of five, so that where the samples fall
/// in each contact does not decide).
fn envelope_decays(window: &[f64]) -> bool {
    let (earlier, later) = window.split_at(window.len() / 2);
    let largest = |p: &[f64]| p.iter().copied().fold(0.0f64, f64::max);
    largest(later) < UNDECAYING_RATIO * largest(earlier)
}

impl EnergyTotals {
    /// The per-tick quantities (trace columns, snapshot).
    pub fn tick_energy(&self) -> TickEnergy {
        TickEnergy {
            work_on_probe_j: self.work_on_probe_j,
            coupling_energy_j: self.coupling_energy_j,
            generated_j: self.generated_j,
            active_work_j: self.active_work_j,
            device_dissipation_j: self.device_dissipation_j,
            net_generated_j: self.net_generated_j,
            passivity_dissipated_j: self.passivity_dissipated_j,
        }
    }

    /// The totals with their verdicts (`/api/stats`, the run summary).
    pub fn report(&self) -> EnergyReport {
        EnergyReport {
            totals: self.tick_energy(),
            largest_rise_j: self.largest_rise_j,
            contacts: self.contacts,
            longest_cycle_run: self.longest_cycle_run,
            active: self.active(),
            oscillating: self.oscillating(),
        }
    }
}

impl EnergyTotals {
    /// `--fail-on active`: the net generated energy rose by more than [`ACTIVE_TOLERANCE_J`].
    pub fn active(&self) -> bool {
        self.largest_rise_j > ACTIVE_TOLERANCE_J
    }

    /// `--fail-on oscillation`: a contact limit cycle ([`OSCILLATION_CYCLES`] undecaying contacts in a row).
    pub fn oscillating(&self) -> bool {
        self.longest_cycle_run >= OSCILLATION_CYCLES
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spring pressed and released slowly along its line, booked exactly: the work on the probe is minus
    /// the spring energy gained (W = -k x^2 / 2 in the limit), so generated stays near zero; here the
    /// force is sampled at the start of each step, so the generated energy is the known ZOH excess
    /// sum k dx^2 / 2 per step.
    #[test]
    fn a_quasi_static_press_generates_only_the_zoh_excess() {
        let k = 1000.0;
        let mut ledger = EnergyLedger::new(0.0);
        let dx = 1e-5;
        let n = 200;
        let mut totals = EnergyTotals::default();
        for i in 0..=n {
            let x = i as f64 * dx;
            let force = DVec3::new(-k * x, 0.0, 0.0);
            totals = ledger.record(
                i as f64 * 1e-3,
                1e-3,
                DVec3::new(x, 0.0, 0.0),
                force,
                DVec3::ZERO,
                0.5 * k * x * x,
            );
        }
        // W = -k dx^2 (0 + 1 + ... + (n-1)) = -k dx^2 n (n - 1) / 2; E_c = k (n dx)^2 / 2.
        let expected = 0.5 * k * dx * dx * n as f64;
        assert!((totals.generated_j - expected).abs() < 1e-15, "{totals:?}");
        assert!(!totals.active());
    }

    /// A directed force `d` on a free hand puts the proxy `d/k` ahead of the probe: the spring without the
    /// directed part is unstretched and holds nothing; a contact reaction `R` on top of it holds `|R|^2/2k`.
    #[test]
    fn the_reaction_energy_leaves_the_directed_stretch_out() {
        let (k, d, r) = (500.0, DVec3::new(1.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 2.0));
        let all = SentShare::ALL;
        assert_eq!(all.reaction_energy_j(k, d / k, d), 0.0);
        let held = all.reaction_energy_j(k, (d + r) / k, d);
        assert!((held - 4.0 / 1000.0).abs() < 1e-15, "{held}");
        // Half sent: a quarter of it (the spring's force scales with the share).
        let half = SentShare::of(DVec3::new(0.5, 0.0, 0.0), DVec3::new(1.0, 0.0, 0.0));
        assert!((half.reaction_energy_j(k, (d + r) / k, d) - 1.0 / 1000.0).abs() < 1e-15);
        // No stiffness: no directed stretch to take out (no division by zero).
        assert_eq!(all.reaction_energy_j(0.0, r, d), 0.0);
    }

    /// A force pushing along the motion does work; booked as active it is split out of the net.
    #[test]
    fn active_work_is_split_from_the_coupling() {
        let mut ledger = EnergyLedger::new(0.0);
        let f = DVec3::new(2.0, 0.0, 0.0);
        let mut totals = EnergyTotals::default();
        for i in 0..100 {
            let x = DVec3::new(i as f64 * 1e-4, 0.0, 0.0);
            totals = ledger.record(i as f64 * 1e-3, 1e-3, x, f, f, 0.0);
        }
        // 2 N over 99 steps of 0.1 mm: 19.8 mJ, all of it active.
        assert!((totals.work_on_probe_j - 0.0198).abs() < 1e-12);
        assert!((totals.active_work_j - 0.0198).abs() < 1e-12);
        assert!(totals.net_generated_j.abs() < 1e-12 && !totals.active());
    }

    /// Twenty contacts every 20 ms whose peak forces are `peak(i)` and into which the probe moves at
    /// `approach(i)` (it steps `approach(i)` ms along x over the tick that begins contact `i`, and stands still
    /// otherwise), booked tick by tick: the ledger's verdict.
    fn oscillating_with(peak: impl Fn(usize) -> f64, approach: impl Fn(usize) -> f64) -> bool {
        let mut ledger = EnergyLedger::new(0.0);
        let mut totals = EnergyTotals::default();
        let mut x = 0.0;
        for cycle in 0..20 {
            for i in 0..20 {
                let t = (cycle * 20 + i) as f64 * 1e-3;
                let f = if i < 10 { peak(cycle) } else { 0.0 };
                if i == 0 {
                    x += approach(cycle) * 1e-3;
                }
                totals = ledger.record(
                    t,
                    1e-3,
                    DVec3::new(x, 0.0, 0.0),
                    DVec3::new(f, 0.0, 0.0),
                    DVec3::ZERO,
                    0.0,
                );
            }
        }
        totals.oscillating()
    }

    /// [`oscillating_with`] the same approach speed into every contact.
    fn oscillating(peak: impl Fn(usize) -> f64) -> bool {
        oscillating_with(peak, |_| 0.1)
    }

    /// Contacts every 20 ms with the same peak, or growing, are a limit cycle; the same contacts decaying are
    /// not one, however slowly, as long as ten contacts take their envelope down by more than 5 %: a
    /// geometric decay by `r` per contact lowers the largest of five contacts by `r^5` from one half of the
    /// window to the next, 0.88 for `r` = 0.975, 0.95 at `r` = 0.9898 (each contact is at least 95 % of the
    /// one before from `r` = 0.95 on).
    #[test]
    fn undecaying_repeated_contacts_are_an_oscillation() {
        for (r, expected) in [
            (1.0f64, true),
            (1.02, true),
            (0.992, true),
            (0.3, false),
            (0.975, false),
            (0.987, false),
        ] {
            assert_eq!(oscillating(|i| r.powi(i as i32)), expected, "r = {r}");
        }
    }

    /// Under a steady push the peak force of a decaying bounce tends to twice the static force, not to zero:
    /// peaks that settle while the speed into each contact falls (by `r` = 0.95 per contact, `r^5` = 0.77) are
    /// a decaying bounce; with the speed steady too they are a limit cycle.
    #[test]
    fn a_bounce_whose_approach_speed_decays_is_not_an_oscillation() {
        let settling = |i: usize| 0.3 + 0.01 * 0.5f64.powi(i as i32);
        assert!(!oscillating_with(settling, |i| 0.95f64.powi(i as i32)));
        assert!(oscillating_with(settling, |_| 0.01));
    }

    /// The contacts of a surface explored with lifts between them, at their peaks each as strong (the mode's
    /// limit) but irregular in between, are no limit cycle: a contact weaker than 95 % of the one before
    /// starts the count again.
    #[test]
    fn irregular_contacts_are_not_an_oscillation() {
        let peaks = [
            2.0, 2.0, 1.9, 2.0, 1.6, 2.0, 1.2, 2.0, 0.2, 0.6, 2.0, 1.5, 0.2,
        ];
        assert!(!oscillating(|i| peaks[i % peaks.len()]));
    }

    /// Every total goes through the atomics and back bit for bit: distinct values in every field (a
    /// field missing from the atomics would come back as its default).
    #[test]
    fn the_stats_atomics_hold_every_total() {
        let totals = EnergyTotals {
            work_on_probe_j: 1.5,
            coupling_energy_j: -0.0,
            generated_j: 1e-300,
            active_work_j: f64::MAX,
            device_dissipation_j: 2.25,
            net_generated_j: -3.0,
            largest_rise_j: 0.125,
            contacts: u64::MAX,
            longest_cycle_run: u32::MAX,
            passivity_dissipated_j: 7.0,
        };
        let stats = EnergyStats::default();
        stats.store(&totals);
        let back = stats.load();
        assert_eq!(back, totals);
        assert!(back.coupling_energy_j.is_sign_negative());
    }
}
