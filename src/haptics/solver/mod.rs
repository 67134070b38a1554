//! The exact proxy solver: the proxy position that minimises the energy of DESIGN.md section 2, with a
//! certificate of its accuracy on every answer.
//!
//! # The maths
//!
//! With probe `p`, coupling stiffness `k` and the sum of directed forces `d`, put `y = p + d/k`. The proxy
//! minimises the k-strongly convex energy
//!
//! ```text
//!     P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)            (plus a constant)
//! ```
//!
//! where `C_i` is the point, the line or the half-space `(x - x_i).q_i >= 0` of primitive `i`. Each distance term
//! is a support function, `s_i dist(x, C_i) = max_{u in U_i} u.(x - x_i)`, with `U_i` a ball of radius `s_i`
//! (point), a disc of radius `s_i` orthogonal to `q_i` (line) or the segment `{-t q_i : 0 <= t <= s_i}` (plane).
//! Minimising over `x` first gives the dual, to be maximised:
//!
//! ```text
//!     D(u) = -|U|^2/(2k) + sum_i u_i.(y - x_i),   U = sum_i u_i,   x(u) = y - U/k
//! ```
//!
//! `-u_i` is the force primitive `i` exerts on the proxy.
//!
//! **Block coordinate ascent.** Holding the others, the best `u_i` is the Euclidean projection of
//! `k (y - x_i) - sum_{j != i} u_j` onto `U_i` (the dual Hessian is isotropic), a closed form. A sweep is O(N).
//! Sweeps alternate direction (symmetric Gauss-Seidel).
//!
//! **Certificate.** For any `x` and any *feasible* `v` (`v_i in U_i`), weak duality gives
//!
//! ```text
//!     gap = P(x) - D(v) = sum_i [ s_i dist(x, C_i) - v_i.(x - x_i) ] + |k (x - y) + V|^2 / (2k),   V = sum v_i
//! ```
//!
//! with every bracket `>= 0`, and strong convexity gives `|x - x*| <= sqrt(2 gap / k)`. Every answer carries a
//! bound built on this ([`certificate`]).
//!
//! # Why the bound never lies
//!
//! 1. *Feasible duals on every exit.* The solver's duals come from projections onto this tick's sets, except a
//!    warm start, whose values were projected onto *last* tick's sets. The certificate projects whatever it is
//!    given onto this tick's sets before it uses it, so no bound rests on a value outside them. The warm start
//!    itself is projected where it is used: a sweep projects each value it writes, the primal method starts
//!    from zero, and a solve that runs out of budget before its first pass projects the warm start and
//!    certifies that. A stalled or exhausted solve returns the point of least energy it saw, with its
//!    certificate ("Budget exits", below); with no primitives the bound is the rounding of `y`. (Until 2026-11-27 the warm start was projected up front as well, once more
//!    than needed: two projections per path tick.)
//! 2. *Rounding only overstates.* Three perturbation facts carry the f64 arithmetic into the argument. (a) If
//!    `E' = E + h` with `h` L-Lipschitz, the minimisers differ by at most `L/k` (compare `E` and `E'` at both
//!    minimisers with strong convexity). So a dual value off its set by `e_i` (a rounded projection is, by a few
//!    ulps of `s_i`) is exactly feasible for a problem whose energy differs by the linear term
//!    `(v_i - v_i*).(x - x_i)`: the bound adds `sum e_i / k`, charged as `8 eps sum s_i / k`; the rounding of `y`
//!    is a linear term too. (b) Each bracket is computed as a sum of non-negative pieces (no cancellation), and
//!    its rounding error (`16 eps (s_i + |v_i|) |x - x_i|` and a relative `16 eps`) is *added*. (c) The residual
//!    `k (x - y) + V` is summed with compensation (Neumaier's; each step's error is computed exactly by
//!    Knuth's TwoSum, which gives the same values without a branch) and its rounding bound added.
//! 3. *No square root of rounding.* Alone, (b) would floor the bound at `sqrt(eps s |x| / k)`, about 1e-10 m,
//!    because a bracket at a kink is linear in the distance to it. Two certificates avoid that; B is formed
//!    first, A only when B misses the tolerance, and the smaller bound is kept.
//!
//!    **B** certifies a nearby exact point `x^` on the kinks (the items within 16 ulps of theirs: the plane the
//!    proxy rests on), where their brackets are exactly zero; primitives pulling with full strength off their
//!    kink take their exact subgradient at `x^` as dual value, bracket exactly zero (what that changes in `V`
//!    shows in the residual); the others keep their bracket, grown by what the move to `x^` can change it. Then
//!    `|x - x*| <= |x - x^| + |x^ - x*|`, and `|x^ - x*|` is `sqrt(2 shares / k) + |residual at x^| / k + L / k`,
//!    with the residual entering *linearly*. `|x - x^|` is bounded by the kinks' distances over the square root
//!    of the smallest positive eigenvalue of `M = sum P_i` (their projectors; `P_i <= M` gives
//!    `|M^+ P_i r| <= |P_i r| / sqrt(lambda)`), so a thin wedge pays its 1/angle; the eigenvalue is discounted by
//!    a bound on the Jacobi method's absolute error (a few hundred ulps of the trace). `x^` exists only if the
//!    kink sets meet. Transversal sets (codimensions adding up to the rank of `M`) always do. Sets that are not
//!    (a point on a plane, three planes through a line) meet only if they pass through a common point, which
//!    rounding cannot confirm, so B takes them only where the meeting is exact by construction, decided without
//!    rounding: a set that contains another coordinate by coordinate (a line along x in the plane z = 0, a
//!    friction point on that plane, two planes with one normal and offset) adds nothing, and two lines in one
//!    coordinate plane cross. Any other non-transversal kinks are left to A.
//!
//!    **A** needs no common point. For any feasible `v` the energy splits exactly as
//!    `P(z) = q(z) + sum_i mu_i(z)`, with `q(z) = k/2 |z - y|^2 + sum_i v_i.(z - x_i)` and the brackets
//!    `mu_i(z) = s_i dist(z, C_i) - v_i.(z - x_i) >= 0`. With `a = x*`, `d = |a - x|` and the residual
//!    `rho = grad q(x) = k (x - y) + V`: strong convexity at the minimiser gives `P(x) - P(a) >= k/2 d^2`, and
//!    `q(a) = q(x) + rho.(a - x) + k/2 d^2`, so `k d^2 - |rho| d + sum_i mu_i(a) <= sum_i mu_i(x) = S`.
//!    *Sharpness:* a kink whose dual value lies inside its set by a margin `m_i` (ball or disc: `s - |v|`;
//!    segment: `min(t, s - t)`) has `mu_i(z) >= m_i (|P_i (z - x)| - delta_i)`, with `delta_i` the distance from
//!    `x` to its kink set, and `sum_i m_i |P_i w| >= Lambda |w|` with `Lambda` the smallest eigenvalue of
//!    `sum_i m_i P_i` (for a point, its margin alone). Hence `k d^2 + (Lambda - |rho|) d <= S + sum_i m_i
//!    delta_i`, and `d` is at most that quadratic's root: *linear* in `S` once `Lambda > |rho|`, which is the
//!    case of a proxy held by a friction point (sticking) or in a corner with room to spare. With no sharp
//!    kink (`Lambda = 0`) the root is at most `|rho| / k + sqrt(S / k)`, never worse than the plain gap bound.
//!    *A point's own sharpness* (2026-11-27): a point at `c` with dual `v` has the share `s |z - c| - v.(z - c)`,
//!    at least `s |w| - v.w - (s + |v|) |x - c|` for `w = z - x`; with one plane or line kink of margin `m`
//!    beside it the two add up to at least `(s - dist(v, Z)) |w|` less their slacks, `Z` the plane's segment
//!    `{t q : |t| <= m}` (the line's disc of radius `m`), because that sum is the support function of
//!    `B(-v, s) + Z`, which contains the ball of radius `s - dist(v, Z)`. So a saturated point (no margin of its
//!    own) beside a plane that pushes with room to spare is sharp unless it pulls along the plane; A takes the
//!    better of this and the kinks' sharpness, over every point item (it need not be a kink: its distance
//!    from `x` enters the slack).
//!    Rounding: the margins are shrunk by their rounding and by the few ulps by which a projection may lie off
//!    its set ((a) above), the shares are summed with their error added ((b)), and `Lambda - |rho|` is rounded
//!    down, which only lengthens the root.
//!
//!    *History.* Until 2026-11-25 B also accepted non-transversal kinks that passed within rounding of a common
//!    point (checked at the least-squares point), the one step verified in floating point rather than proved,
//!    and it under-reported once: a friction point 3.8e-17 m off a tilted plane was taken as on it, with a bound
//!    of 8.1e-18 m against a true error of 3.96e-17 m (a property test found it). Now B refuses such kinks and A
//!    certifies that tick at 1.9e-15 m (`solver_props::a_friction_point_within_rounding_of_a_tilted_plane_is_
//!    not_taken_as_on_it`, asserted honest and certified on every tick). The price: non-transversal kinks that
//!    meet but neither exactly by construction nor with room to spare (three tilted planes through one line,
//!    with the proxy sliding along it) get A's square-root bound, about 1e-9 m, and end `Stalled`.
//!    `cargo run --release --example uncertified -- 400000` (the property tests' random scenes, 400 000 of each
//!    kind), before / after the change: without lines 0 / 2 not certified, with lines 5 / 4, with lines and
//!    the dual method alone 9 / 4. So the new misses are about 1 in 200 000 scenes without lines, and fewer
//!    than the misses with lines that were there before (bounds up to 2e-4 m, left alone).
//!
//!    *The stick/slip boundary on a tilted plane* (found 2026-11-27 by the friction property test at case 692
//!    of 4 000; in the regression file). A friction point that lies 6.8e-20 m in front of a tilted plane
//!    (within rounding, as the previous proxy always is), asked by the coupling for 0.3740254 N against its
//!    0.3740282 N (7.6e-6 to spare, relative): the minimiser lies on the plane 1.7e-17 m from the point, the
//!    point pulling with all of its strength almost along the plane. B cannot take both kinks (not
//!    transversal, not meeting exactly), and with the plane alone the point's pull turns by up to 2 s / margin
//!    per metre the proxy is moved, which for a margin of 1.7e-17 m is no bound at all. A's sharpness is the
//!    point's 2.8e-6 N to spare, against shares of about 1e-17 J (the rounding of a plane anchored 4 mm away),
//!    so its bound is 8.9e-12 m: honest (the true error is 1.9e-17 m) but above the 1e-12 m tolerance, and the
//!    tick ends `Stalled` after its sweep budget for stalling (about 2 000 sweeps). This was so before the
//!    2026-11-27 changes too (same bound, checked on the previous commit). Near the boundary A's bound is about
//!    S / margin, S the rounding charged on the plane's share (`16 eps (s + t) |x - x_p|`, `x_p` its anchor):
//!    the property test asserts an honest bound of at most 1e-8 m where that estimate comes within a factor
//!    of ten of the tolerance, and certification on every other tick. (In the servo loop the surface plane
//!    is anchored at the proxy, so `|x - x_p|` is one tick's motion and the band far narrower.)
//!
//! **Primal Newton first** ([`newton`]). Every cold or large solve starts with an active-set Newton method on
//! `x` itself: O(N) passes, each followed by a 3x3 Newton step on the kinks the proxy is held on and an exact
//! line search over the planes crossed; at the end the kink multipliers are recovered, and that dual is what
//! the certificate above checks. Planes whose side at the answer is proven (strong convexity bounds
//! `|x - x*|` by `|subgradient| / k`) are screened out of the passes. The gradient is summed with
//! compensation, so Newton converges to the true zero and not to a rounding artefact of N forces.
//!
//! **Dual method** (the solver before the primal one; the fallback, and the first choice for small scenes that
//! can reuse last tick's dual). Block sweeps, and an active-set finish ([`active_set`]): near-parallel planes
//! make sweeps crawl (like alternating projections), so after a few sweeps the solver guesses which primitives
//! sit on their kink, solves the smooth model on that affine set with Newton steps, recovers the kink
//! multipliers by least squares and flips statuses until the guess is consistent. The answer is accepted only
//! when the certificate says so; otherwise sweeps go on from the improved dual.
//!
//! # Speed: what was tried, and what the benchmark says
//!
//! `cargo bench --bench solver` prints the table docs/solver.md quotes, with the dual method alone
//! (`primal_newton: false`) side by side in the same run. Shared 2-vCPU machine under load, 2026-11-24:
//!
//! - *Primal Newton* (kept, the default): against the dual method alone, 1.8x to 2.9x faster on the wedges and
//!   on 10 and 100 random primitives, 20x on 1 000 (173 us against 3.45 ms), 33x on 3 000 mixed (0.53 ms
//!   against 17 ms), and it certifies 10 000 mixed primitives in 2.1 ms where the dual method gave up after 4 s.
//!   Two fixes made it work at scale: a line search that stops at a point or line only when the other terms'
//!   slope there is within what it can hold (otherwise Newton cycled onto points that cannot hold the proxy),
//!   and compensated sums for the gradient and for `y` (a plain sum of 7 500 forces, and the old worst-case
//!   bound on `y`'s rounding, left 10 000 primitives at a 2e-12 m floor).
//! - On the servo loop's usual tick (a plane and a friction point, warm-started) the primal method took 2 us
//!   where one or two dual sweeps from last tick's dual take 0.19 us, so small warm-started scenes (at most 16
//!   non-directed primitives) go to the dual sweeps first. If two active-set rounds do not finish such a
//!   scene, the primal method runs once from the best point (2026-11-25: a proxy held by a friction point
//!   beside a plane kept the dual method stalled for 2 000 sweeps, bound 3.6e-7 m, before and after the
//!   certificate's fix; found by `solver_props::the_bound_holds_on_a_plane_with_friction_tick_after_tick`).
//! - *Screening* of planes: it removes work only in the last passes (the proven radius is large until Newton has
//!   nearly converged), so its gain is small; kept because it never changes the answer. Not measured apart.
//! - *Plain sums far from the answer* (kept): the compensated gradient sum costs several times a plain one per
//!   primitive, and is only needed once the gradient is a small difference of large forces. Passes now sum
//!   plainly until the reduced gradient is below 1e-4 of the force scale, then with compensation (a face found
//!   done on a plain sum that does not certify is checked again at the same point with compensation; only
//!   compensated passes screen). Instructions
//!   per cold solve (callgrind, deterministic, load-independent), before / after: 10 random primitives
//!   16 977 / 15 686 (-8 %), 100: 145 578 / 128 232 (-12 %), 1 000: 2 158 745 / 1 936 443 (-10 %); the 1 degree
//!   wedge 6 998 / 7 156 (+2 %); pass counts unchanged (6, 8, 13). These counts are of a first version that
//!   re-checked every face found on a plain sum; the kept one re-checks only a face that does not certify (it
//!   saves the extra pass on one point), and was measured only by the bench.
//! - *Ordering line-search breakpoints a chunk at a time* (16 selected in O(n), then sorted, instead of one
//!   full sort): tried and dropped, 1 000 primitives took 7 % more instructions (2 077 628 against 1 936 443).
//! - *Sorting breakpoints by integer keys* (2026-11-27, kept): each breakpoint is (the bits of its step
//!   fraction, item), sorted by the bits (non-negative floats order as their bits do; `-0.0` is turned into
//!   `+0.0` first), instead of `total_cmp` on (fraction, slope jump, item); a plane's jump is recomputed when the
//!   walk reaches it. Same passes everywhere. Instructions per cold solve (callgrind), before / after: 1 000
//!   random 1 451 930 / 1 409 861 (-2.9 %), 3 000 mixed 3 242 322 / 3 160 083 (-2.5 %), 10 000 mixed
//!   18 117 120 / 16 971 239 (-6.3 %), 20 other scenes of 1 000 (`seeds 1000 20`) 1 309 511 / 1 279 818 per
//!   solve; wedges 6 293 / 6 310, 10 random 13 669 / 13 659, 100: 114 851 / 114 493. Quick timings alternated
//!   twice (medians): 1 000 random 80.3, 79.5 / 79.2, 77.8 us; 10 000 mixed 1.24, 1.23 / 1.19, 1.17 ms.
//! - Earlier, on the dual method: over-relaxation (1.5, 1.8) was 1.2x to 3x slower; longer rounds helped 1 000
//!   primitives only; certifying only at the end of each round for more than 16 primitives was 1.8x faster on
//!   1 000 (kept).
//!
//! - *Cheaper cold solves* (2026-11-24 evening; the first two kept). Instructions per solve (callgrind,
//!   `examples/solver_instructions.rs`, deterministic), main before, then the steps added one by one:
//!
//!   | case | before | certificate | + ahead (kept) | + shortened step (dropped) |
//!   |---|---|---|---|---|
//!   | wedges (5 and 1 degree) | 6 609 | 6 198 | 6 108 | 6 146 |
//!   | 10 random | 15 867 | 14 784 | 13 469 | 13 535 |
//!   | 100 random | 129 848 | 120 096 | 112 438 | 117 446 |
//!   | 1 000 random | 1 951 968 | 1 854 380 | 1 771 556 | 3 577 767 |
//!   | 3 000 mixed | 5 465 080 | 5 172 281 | 5 064 918 | 3 330 991 |
//!   | 10 000 mixed | 18 467 221 | 17 491 153 | 16 734 709 | 17 899 875 |
//!   | path, per tick | 1 693 | 1 475 | 1 338 | 1 338 |
//!
//!   *Certificate:* B is formed first and A only when B misses the tolerance (A, before it had sharpness, never
//!   certified with a primitive at its kink, so on the path and at every converged kink it was pure cost); one
//!   eigen-decomposition instead of two in the kink shift; the kinks are remembered by index, so the
//!   consistency check at a point visits them instead of every primitive, and their projector sum is built
//!   only in the general case. *Ahead:* a last full Newton step short enough for quadratic convergence is
//!   certified at its end without the pass that would confirm it ([`newton`], step 5): one pass less per solve
//!   on most scenes (10 random: 6 to 5 passes; 100: 8 to 7; 1 000: 13 to 12). The version kept also requires
//!   every primitive outside W to stay clear of the certificate's kink threshold at the step's end (so the
//!   duals it leaves are the certificate's); it counts 6 110, 13 493, 112 486, 1 771 830, 5 065 675,
//!   16 737 233 and 1 338 in the table's rows.
//!   *Shortened step* (dropped): a rejected step cut to the minimiser of the parabola through the energy and
//!   slope at its start and the energy at its end (within t/10 to t/2) instead of halved. Over other scenes
//!   (`solver_instructions seeds`) it was better or level: 20 scenes of 1 000 primitives 1 749 827 against
//!   1 968 673 instructions per solve with halving (201 against 251 passes in all), 100 scenes of 100:
//!   132 743 against 135 975, 6 of 3 000: level, 400 of 10: level. But on the benchmark's 1 000 scene it takes
//!   a detour (a point joins W from the line search's near-pass rule and is dropped with a multiplier 1 250
//!   times its strength: 24 passes instead of 12), which made the exact solver slower there than Euler to the
//!   same accuracy (280 us against 215 us in one bench run), a case halving wins. Worth another look together
//!   with the near-pass rule.
//!   Quick timings of main and this version, alternated twice in one run (`solver_instructions time`,
//!   medians, loaded 2-vCPU VM, 2026-11-24 22:19 UTC), before / after: path 202, 198 / 147, 148 ns per tick;
//!   wedges 625 to 646 / 530 to 536 ns; 10 random 1.41, 1.43 / 1.09, 1.09 us; 100: 10.5, 10.9 / 8.5, 8.6 us;
//!   1 000: 154, 151 / 140, 142 us; 3 000 mixed 427, 428 / 407, 406 us; 10 000 mixed 1.69, 1.69 / 1.61,
//!   1.56 ms.
//! - Where the time goes (callgrind, 10 random primitives): the passes over eight primitives, the Newton steps'
//!   3x3 algebra and the line search are about 84 %, the one certificate 16 %. On 1 000 primitives the
//!   passes and line searches are about 90 %; a pass with its line search costs about 135 instructions per
//!   primitive. On the path
//!   the certificate is 46 % of the tick (610 of 1 338 instructions), the rest is set-up, the warm projection
//!   and one sweep, spread thinly over many lines: under 100 ns needs about 850 instructions on this machine.
//! - *Fewer passes* (2026-11-25, kept; [`newton`]'s header, steps 3 to 5). (a) *Early leave:* with one kink
//!   in W, its multiplier predicted at the face's minimiser (`g + H d`) is checked every pass; far outside its
//!   set (by over a quarter of its strength) the kink leaves at once (the benchmark's 1 000 scene converged
//!   three passes on a plane that then asked for 2.7 N against its 0.96 N). (b) *Hold check:* a point or line
//!   passed near joins an empty W only if the other terms' whole modelled force on it is at most twice its
//!   strength (a point joined with 1 250 times its strength, and leaving it threw the proxy 0.5 m off: the
//!   "detour" that made the shortened step lose last time). (c) *Shortened step*, the parabola of the entry
//!   above, kept now that (b) removed its detour. (d) A step fraction within 1e-6 of 1 counts as full for
//!   certifying ahead (rounding had left it just below 1). (e) The line search reads only items whose kink
//!   is within `|d|` of `x` (distances kept from the pass; the others can neither cross nor pass near),
//!   the compensated sum is branch-free (TwoSum: the same values), the split sweeps over dependent kinks stop
//!   at a fixed point, and a kink added by the line search does not rebuild its face twice. None of this
//!   touches the certificate, which checks every answer from scratch as before, so the argument above stands
//!   unchanged. Passes (`solver_instructions seeds`, main / this): 20 scenes of 1 000 primitives 251 / 159,
//!   100 of 100 815 / 706, 200 of 30 1 981 / 1 509, 400 of 10 2 217 / 2 040, 6 of 3 000 62 / 54; the
//!   benchmark's 1 000 scene 12 / 9, 3 000 mixed 11 / 6. Without (c) the 20 scenes took 189 passes (the
//!   benchmark's 10), with (a) alone 220; (c) without (b): 165, but 12 on the benchmark's scene. Instructions
//!   per solve (callgrind, main / this): wedges 6 092 / 5 965; 10 random 13 695 / 13 347; 100: 114 806 /
//!   112 799; 1 000: 1 813 405 / 1 424 555 (-21 %); 3 000 mixed 5 166 935 / 3 191 493 (-38 %); 10 000 mixed
//!   17 044 670 / 17 819 592 (+5 %: the same 10 passes by another way); path 1 349 / 1 296 per tick (of which
//!   26 from inlining `project`). Quick timings alternated main, this, main, this (`solver_instructions
//!   time`, medians, 2-vCPU VM at load 3.2 to 3.4, 2026-11-25 01:01 UTC, before the inlining): path 178, 158 /
//!   174, 160 ns; 10 random 1.30, 1.44 / 1.28, 1.10 us; 100: 10.2, 9.6 / 10.2, 8.8 us; 1 000: 155, 153 / 125,
//!   109 us; 3 000 mixed 501, 483 / 294, 257 us; 10 000 mixed 1.80, 1.77 / 1.77, 1.73 ms.
//! - *Capping a cold solve's first step* at the scene's coordinate scale (the first step on the 1 000 scene
//!   overshoots and is shortened after a wasted pass): tried and dropped; the 1 000 scene kept its 9 passes,
//!   3 000 mixed went from 6 to 11, 100 random needed the dual fallback (13 sweeps), 100 other scenes of 100
//!   took 753 passes against 706.
//! - *Cheaper small cold solves* (2026-11-27, kept; [`newton`]'s header). (a) *The start:* a cold solve begins
//!   where one dual block sweep from zero leads, not at `y` (Newton's first step from `y` overshoots: the
//!   pull of a point a few millimetres off is a poor quadratic). (b) No screening for at most 16 primitives in
//!   the passes (it cost 468 of 13 659 instructions on 10 random primitives and saved nothing). (c) With no
//!   kink the Newton step is an LDL^T solve of the Hessian, not products with the identity projector and a
//!   general inverse. (d) Certifying ahead recomputes the points' and lines' subgradients inline (the same
//!   values). The certificate is untouched and still checks every answer from scratch. Instructions per cold
//!   solve (callgrind), before / after: wedges 6 310 / 5 123 (3 / 2 passes); 10 random 13 659 / 11 038
//!   (5 / 4); 100: 114 493 / 89 631 (7 / 5); 1 000: 1 409 861 / 855 787 (9 / 5); 3 000 mixed 3 160 083 /
//!   2 820 393 (6 / 6); 10 000 mixed 16 971 239 / 9 474 803 (10 / 6); path unchanged (dual first). Other scenes
//!   (`solver_instructions seeds`, passes in all and instructions per solve, before / after; none uncertified
//!   either way): 400 of 10: 2 040 / 1 661 passes, 13 967 / 11 381; 200 of 30: 1 509 / 1 112, 47 347 /
//!   33 240; 100 of 100: 706 / 537, 119 674 / 94 143; 20 of 1 000: 159 / 111, 1 279 818 / 921 668; 6 of
//!   3 000: 54 / 39, 4 071 512 / 3 009 370. (b) to (d) alone: 10 random 11 879, wedges 6 035. Quick timings
//!   (`solver_instructions time`, medians, before / after, alternated, 2-vCPU VM, 2026-11-27 15:20 UTC):
//!   wedges 368 to 399 / 292 to 317 ns; 10 random 814 to 866 / 753 to 786 ns; 100: 6.26, 6.29 / 5.66, 5.50 us;
//!   1 000: 76.1, 76.4 / 53.4, 51.8 us; 10 000 mixed 1.18, 1.19 / 0.71, 0.71 ms; but 3 000 mixed 175.7 to
//!   178.0 / 177.8 to 183.0 us (about 2 % slower with 11 % fewer instructions and the same passes: the
//!   sweep is a serial chain, each primitive's square root and division waiting on the sum before it).
//!   Tried and dropped: more sweeps (2, 3, 4 and 6 from zero: fewer passes on 10 primitives, 1 419 to 1 001
//!   for the 400 scenes, but more instructions from 100 primitives up: 20 of 1 000 took 1.03 to 1.16 million
//!   per solve against 0.94 with one sweep); sweeping from the subgradients at `y` instead of zero (better on
//!   10, worse from 100 up: 20 of 1 000 180 passes); updating 4 primitives at a time from one sum (to overlap
//!   their square roots): 10 000 mixed then needed the dual fallback (23.2 million instructions).
//! - *Fewer square roots and divisions* (2026-11-27 evening, kept). Certificate B tests a point's or line's
//!   saturation on the unprojected dual (`|proj u|^2 = min(|P u|^2, s^2)`), so a saturated one costs no
//!   projection; certifying ahead adopts B's dual (`certificate::certify_into`) instead of computing the
//!   subgradients again; the primal method compares lengths squared; the LDL^T solve takes three reciprocals
//!   instead of six divisions (then 10 307 on 10 random once the scratch dual was only resized, not cleared).
//!   Instructions per cold solve: 10 random 10 705 / 10 359, 100: 86 767 / 83 532,
//!   1 000: 827 376 / 808 631; the path 0.3 % and the 5 degree wedge 1.7 % more (the adopted dual's buffer). Time
//!   (`solver_instructions time`, three alternations with the previous binary, 2-vCPU VM, 17:50 UTC): 10 random
//!   737 / 698 ns, 100: 5.34 / 5.04 us, 1 000: 49.8 / 47.6 us, 3 000 mixed 168 / 160 us, 10 000 mixed 590 /
//!   553 us. The time fell more than the instructions: on these scenes the square roots and divisions are
//!   what the passes wait on. Tried and dropped: the pass as two loops (points and lines with no branch on the
//!   kind, a point being a line with no direction; then the planes): fewer instructions, but 1 000 random
//!   9 % slower and 3 000 mixed 7 % slower.
//! - *Third-order correction of the last step* (2026-11-27 night, kept; [`newton`]'s header, step 5). A short
//!   full step with W empty gets Chebyshev's correction `-H^-1 T[d, d] / 2` and is certified at its end, when
//!   the last two steps predict that it lands within the tolerance; the pass is kept out of line (its code no
//!   longer shifts with the iteration around it). Instructions per cold solve (callgrind), before / after:
//!   10 random 10 307 / 9 621 (4 / 3 passes), 100: 83 328 / 82 968, 1 000: 806 650 / 802 284, 3 000 mixed
//!   2 699 571 / 2 655 423 (6 / 5 passes), 5 degree wedge 5 206 / 5 319 (+2 %, the out-of-line pass). Other
//!   scenes (`solver_instructions seeds`, passes in all and instructions per solve): 400 of 10 1 661 / 1 435,
//!   10 697 / 10 476; 200 of 30 1 112 / 1 012, 31 319 / 30 818; 100 of 100 537 / 490, 88 166 / 86 721; 20 of
//!   1 000 111 / 106, 874 937 / 859 746. The passes fall more than the instructions: `T` costs about half a
//!   pass. Time (`solver_instructions time` and `timeseeds`, three alternations, 2-vCPU VM, 21:00 UTC): 10
//!   random 714 to 722 / 679 to 683 ns, 100: 5.18 to 5.26 / 5.20 to 5.25 us, the 400 scenes of 10 800 to 806 /
//!   787 to 802 ns, the 100 of 100 5.69 to 5.77 / 5.67 to 5.74 us, the 200 of 30 2.10 to 2.13 / 2.13 to 2.15
//!   us; one run each: 1 000 random 48.9 / 48.7 us, 3 000 mixed 170 / 157 us, 10 000 mixed 586 / 543 us.
//!   Tried and dropped: the correction on every full step with W empty (1 321 passes for the 400 scenes of 10,
//!   but more instructions, and the benchmark's 10 scene still 3 passes); more dual sweeps at the start (2, 3
//!   or 4: 1 188, 1 033 or 959 passes for the 400 scenes, but a sweep over eight primitives costs about 100 ns,
//!   a serial chain of square roots and divisions); a Jacobi start (each item projected from zero alone, the
//!   sum halved: no chain; 12 to 17 % faster on scenes of 16 to 30 primitives, level at 50, but 50 % slower at
//!   100 and 20 % on the wedges); the start's sweep with an approximate inverse square root (a bit-level guess
//!   and one Newton step, 0.2 % off: 10 random 2.5 % faster, but one point is then no longer solved by its
//!   first pass).
//!   Then three trims (same passes everywhere): the pass keeps its clearance with a comparison instead of
//!   `f64::min` (whose NaN rule cost a few instructions per item), a cold start sets each item's state once
//!   (at the sweep's point, not first at `y`), and a cold solve sizes its dual without per-item work.
//!   Instructions per cold solve, before / after: 10 random 9 621 / 9 393, 100: 82 968 / 79 951, 1 000:
//!   802 284 / 767 970, 3 000 mixed 2 655 423 / 2 551 958, 5 degree wedge 5 319 / 5 216; 400 scenes of 10
//!   10 476 / 10 245. Time (three alternations): the path 97 to 99 / 93 to 94 ns, 100 random 5.27 to 5.30 /
//!   5.18 to 5.19 us, 10 random level (665 to 704 / 681 to 700 ns); one run each: 1 000 random 48.9 / 47.1 us,
//!   3 000 mixed 158 / 154 us, 10 000 mixed 552 / 539 us.
//!   *Where the 10 random primitives' time goes* (about 680 ns; each part run twice in a chain and the
//!   difference timed, which measures its latency, partly hidden in the real solve, so the parts overstate):
//!   a pass about 65 ns (three of them), the certificate about 110 ns, the start's sweep about 97 ns (a serial
//!   chain; yet sweeping two items at a time from one sum, which halves the chain, was not faster), a line
//!   search up to 20 ns, the third-order term up to 50 ns (computing it from `1 / rho` kept by the pass,
//!   without its two divisions per item, was not faster either), and the rest (the primitives copied in, the
//!   Newton steps, the bookkeeping). Under 500 ns needs a cut in every part, not one: a structure-of-arrays
//!   pass over small scenes and leaner set-up are what is left to try.
//!   Later the same evening, certificate B's first loop reads each item through one `match` on its kind
//!   (`look`: the kink distance and the full-strength test together, a line's offset across it formed once)
//!   instead of two functions each with its own, and a cold start sets its states in the visit that looks for
//!   kinks. Same passes and same bounds everywhere (`uncertified -- 400000` unchanged: 2 / 1 / 4). Instructions
//!   per solve, before / after: 10 random 9 354 / 9 167, 100: 79 759 / 78 059, 1 000: 766 854 / 749 867,
//!   3 000 mixed 2 556 766 / 2 505 766, 5 degree wedge 5 230 / 5 223, the path 1 201 / 1 187 per tick; the
//!   400 scenes of 10 10 193 / 10 008. Then the third-order term reads the pass's force `s n` and distance
//!   instead of recomputing the offset (one division per item instead of two): 10 random 9 167 / 9 129, the
//!   400 scenes of 10 10 008 / 9 985, 3 000 mixed 2 505 766 / 2 496 906, the rest level. Tried and dropped
//!   the same evening: `w n` formed once for the pass's Hessian (the compiler already does; written from the
//!   force instead, 1.4 % more instructions), and plain sums throughout for small scenes (compensation is not
//!   what a pass over ten primitives costs: 0.2 % more).
//!   Building with `-C target-cpu=native` (AVX-512 here) was 3 to 8 % faster on 10 random primitives, and fat
//!   LTO with one codegen unit about 3 %; neither is used (the first makes a binary that stops with an illegal
//!   instruction on an older processor, the second multiplies the test build's link time), and neither is
//!   near the 26 % that N = 10 lacks.
//!   Then two fixes found by sampling where the time goes (`perf record -e cpu-clock` on `solver_instructions
//!   cold random10`; this VM has no hardware counters, but the sampled clock shows stalls that instruction
//!   counts do not): the 3x3 solve of the Newton step and of the third-order correction by cofactors, one
//!   division instead of an LDL^T factorisation's three in a row (same passes; 200 scenes of 30: 1 012 / 1 010);
//!   and the items copied in field by field (the copy of a whole `Item` built on the stack stalled on store
//!   forwarding: 46 % of `solve_inner`'s samples on one load, 9.9 % of the solve, now 5.1 %). Time, three
//!   alternations in one run against the commit before this evening's changes: path 94 to 95 / 86 to 88 ns,
//!   10 random 682 to 698 / 614 to 623 ns, 100 random 5.20 to 5.24 / 4.79 to 4.86 us, 1 000 random 47.8 to
//!   48.1 / 44.0 to 44.4 us, 3 000 mixed 156 to 157 / 143 to 150 us, 10 000 mixed 559 to 565 / 513 to 530 us;
//!   the 400 scenes of 10 816 to 831 / 742 to 743 ns. Tried and dropped: the pass's energy scale derived from
//!   its energy (one accumulator fewer in the loop; 10 random level, 100 random 3 % slower).
//!   Then the cold start of scenes of up to 128 items: the damped Jacobi sum instead of the Gauss-Seidel sweep
//!   (newton.rs `start_sum`, with the pass counts that chose the damping and the bound). The sweep was a fifth
//!   of the 10-primitive solve in the sampled profile, a chain of eight square roots and divisions each
//!   waiting on the one before; the Jacobi sum's items are independent. Same bounds (`uncertified -- 400000`:
//!   2 / 1 / 4). Passes: 400 scenes of 10 1 435 / 1 460, 200 of 30 1 010 / 956, 100 of 100 490 / 489, 10
//!   random 3 / 3, 100 random 5 / 6. Time, three alternations: 10 random 593 to 599 / 522 to 540 ns, 100
//!   random 4.70 to 4.76 / 4.59 to 4.68 us, wedges 321 to 328 / 314 to 317 ns, the 400 scenes of 10 730 to 741
//!   / 657 to 661 ns, the 200 of 30 1.94 to 1.97 / 1.60 us, the 100 of 100 5.18 to 5.24 / 4.59 to 4.69 us;
//!   1 000 random and the mixed scenes (the sweep, unchanged) level. Tried after it and dropped (level in
//!   three alternations, 10 random 530 to 541 / 531 to 535 ns): certificate B's `2 s / margin` from the
//!   `s / distance` it already has (no second division per point or line), and no sum over a cold dual that
//!   is all zeros.
//!   2026-11-28, five trims for small scenes, found by sampling (`perf record -e cpu-clock`) where a 10-primitive
//!   solve waits: (1) the iteration is compiled twice (newton.rs, `Workspace::solve`), with the pass inlined
//!   for scenes of up to 16 primitives: out of line, the pass's model came back through memory and the
//!   iteration read its Hessian with loads spanning two of the pass's stores, which stall store forwarding;
//!   (2) the Jacobi start's terms are summed in the visit that sets up the items, and a damped Jacobi start
//!   (more than four items) skips the visit looking for kinks the start sits on (it stops short of every
//!   kink); (3) the line search decides `min(1, -slope / curvature)` by a comparison, the division off the
//!   critical path; (4) the third-order correction reuses the Newton step's cofactors (no second division);
//!   (5) a certified primal answer returns without summing its dual. Same passes and bounds everywhere
//!   (`uncertified -- 400000`: 2 / 1 / 4; seeds of 3, 5, 10, 30, 100 and 1 000 primitives: the same passes).
//!   Instructions per cold solve, before / after: 10 random 8 923 / 8 781, 5 degree wedge 5 235 / 5 210, 100
//!   random 89 698 / 84 890, 1 000 random 745 969 / 746 560, 3 000 mixed 2 485 791 / 2 476 177; 400 scenes of
//!   10 10 008 / 9 951, 200 of 30 27 472 / 25 918, 100 of 100 81 529 / 76 540. Time (`solver_instructions
//!   time`, three alternations in one run against the commit before, 2-vCPU VM, 01:30 UTC): 10 random 531 to
//!   554 / 477 to 498 ns, wedges 316 to 318 / 290 to 293 ns, 100 random 4.70 to 4.72 / 4.54 to 4.56 us, the
//!   path level (84 to 86 ns); the 400 scenes of 10 (`timeseeds`, ten alternations, medians) 672 / 634 ns. The
//!   large scenes, whose code is the same but for the cold-start branches, came out slower in every
//!   alternation, without more instructions: 1 000 random 43.0 to 43.1 / 44.6 to 45.7 us, 3 000 mixed 141
//!   to 147 / 147 to 149 us, 10 000 mixed 504 to 515 / 517 to 525 us (the sampled profile puts it in the
//!   start's Gauss-Seidel sweep, compiled differently; forcing that sweep out of line brought 1 000 within 1 %
//!   but cost the wedges their gain). Kept: those sizes are far inside their goals and ahead of Euler; N = 10
//!   is the goal with the least room. Tried and dropped: the pass inlined at every size (100 random 4 % slower: 9 %
//!   more instructions in its loop); the pass over small scenes walking the item slices directly instead of
//!   the index list (2 % fewer instructions, but slower in time: 662 / 646 ns on the 400 scenes); the line
//!   search and third-order term forced inline (level); the third-order (Chebyshev) step on every full step
//!   with W empty, not only the last, at any step length up to the clearance (1 224 instead of 1 460 passes
//!   for the 400 scenes of 10, but level in time and the benchmark's 10 scene still 3 passes: its second
//!   corrected step lands 2.1e-12 m from the answer, short of the 1e-12 m tolerance); skipping the kink visit
//!   on every cold start (the wedges then took 3 passes instead of 2: the start put the proxy on the plane
//!   that pushed alone); and, after the bench run, the small scenes' pass as one loop per kind (points,
//!   lines, planes: no branch on the kind per item) with the per-item work in shared accumulator methods
//!   (10 random 8 781 / 8 549 instructions, but in time 484 / 502 ns, the wedges 293 / 306 ns, and 100 random
//!   7 % slower, its out-of-line pass compiled differently through the shared methods).
//! - Not done as of 2026-11-25 (the path has since come under 100 ns, below): the path (certificate 585 of 1 296
//!   instructions per tick, the rest set-up, projections and one sweep spread over many lines) and N = 10 (13 347
//!   instructions then, 11 038 after the entry above: 4 passes, a pass over eight primitives about 1 000
//!   instructions and its step, line search and bookkeeping about 900 more (measured before that entry), and a
//!   certificate of about 2 100; under 500 ns needs about 7 000) need a different structure, not a trim: a
//!   specialised certificate for a proxy on one plane with a saturated friction point (1 999 of the 2 000 path
//!   ticks take one dual sweep and one certificate, and in all but 16 of them the proxy slides: a plane kink and a
//!   saturated point), and for small N cheaper iterations (5 passes of about 2 200 instructions each, each with its
//!   3x3 step and line search, and a certificate of about 2 200 over eight primitives). Also not tried: a
//!   structure-of-arrays layout for the passes, an O(active) re-check of last tick's active set for warm large
//!   scenes.
//!
//! The issue's goals for cold starts (path < 100 ns, N = 10 < 500 ns, N = 100 < 10 us, N = 1 000 < 100 us,
//! 3 000 mixed < 1 ms) are checked by the bench itself: `VOXHAP_BENCH_DOCS=1 cargo bench --bench solver`
//! writes the measured table, with its "met" column computed, into README.md and docs/solver.md. As of the
//! last run (2026-11-28 01:16 UTC) all are met, N = 10 by a small margin (484 ns; 484 to 512 ns in five runs
//! that hour, one over; where that time goes is in the entries above and in docs/solver.md). On this shared
//! machine only side-by-side ratios and instruction counts are steady.
//! *The path tick* (2026-11-27): 1 327 to 1 216 instructions (callgrind, `solver_instructions path`, 22 000
//! ticks), 109 to 93 ns in `solver_instructions time` alternated twice, from rounding terms bounded by
//! 1-norms instead of lengths (no square roots), a saturated point's subgradient scaled by the distance the
//! certificate already has, and no up-front projection of a reused dual (every use projects it).
//!
//! # Real time
//!
//! `Solver` owns its workspace. After the first solve with N primitives, solving any scene of at most N
//! primitives allocates nothing (a counting-allocator test proves it). The budget bounds sweeps and, when a
//! clock is given, nanoseconds; the solver always returns its best point with its certificate.
//!
//! # Budget exits
//!
//! An exit without a certified answer (budget spent, or stalled) returns the point of least energy among the
//! start (`previous_proxy_m`, or `y` for a cold solve: where the coupling alone puts the proxy), the best
//! certified point and the primal method's last accepted point. The energy is computed exactly as the sum
//! of its terms ([`energy`], O(N)) with a bound on its rounding, and a point replaces the start only where its
//! energy is lower by more than both roundings: so the answer's energy is never above the start's. Iterates
//! are not monotone in energy without this: the dual method's points `y - U/k` are not descent steps, and
//! a cold primal start (a damped dual sum) on 10 000 primitives lies metres away (`voxhap solve
//! --max-sweeps 2` returned a proxy 7.2 m off, 3.6 kN, where `y` was 0.32 m from the answer). The returned
//! point's bound is the smaller of its certificate with the current dual (the sweeps' dual ascends) and with
//! its own exact subgradients (`|grad P| / k` off the kinks); either is a valid bound for that point, and
//! `primitive_forces_n` reports the dual of the one kept. This exit costs up to three energy evaluations
//! and two certificates (about five passes) beyond the budget; a certified solve never takes it, so certified
//! solves cost what they did: instructions per solve (callgrind, `solver_instructions`), before / after the
//! exit was added, 10 random primitives 8 781 / 8 786, 1 000: 748 103 / 748 110, 10 000 mixed 8 342 106 /
//! 8 342 113, the path 1 176 / 1 176 per tick.

pub mod active_set;
mod certificate;
pub mod linalg;
mod newton;

use crate::clock::Clock;
use crate::haptics::primitive::{Primitive, PrimitiveKind};
use certificate::{certify, CompensatedSum, Frame};
use glam::DVec3;
use serde::Serialize;

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverConfig {
    /// Stop when the certified error bound `sqrt(2 gap / k)` is at most this many metres.
    pub tolerance_m: f64,
    /// Most block-coordinate sweeps per solve.
    pub max_sweeps: u32,
    /// Most wall-clock nanoseconds per solve; only enforced by [`Solver::solve_with_clock`].
    pub max_time_ns: u64,
    /// Sweeps between active-set attempts.
    pub sweeps_per_round: u32,
    /// Status flips allowed within one active-set attempt.
    pub max_flips_per_round: u32,
    /// Reuse the previous solve's dual variables when the primitive list has the same kinds in the same order.
    pub warm_start_dual: bool,
    /// Over-relaxation of the block updates, in `[1, 2)`: `u_i <- proj(u_i + w (u_i^best - u_i))`. 1 is plain
    /// block coordinate ascent.
    pub relaxation: f64,
    /// Try the primal Newton method ([`newton`]) first; `false` runs the dual method alone (the solver before
    /// the primal method existed, kept for comparison in the benchmark).
    pub primal_newton: bool,
    /// Screen out planes that provably keep their side at the answer (primal Newton only).
    pub screening: bool,
}

impl Default for SolverConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl SolverConfig {
    /// The defaults, usable in constants.
    pub const DEFAULT: Self = Self {
        tolerance_m: 1e-12,
        max_sweeps: 100_000,
        max_time_ns: u64::MAX,
        sweeps_per_round: 6,
        max_flips_per_round: 48,
        warm_start_dual: true,
        relaxation: 1.0,
        primal_newton: true,
        screening: true,
    };
}

/// One proxy problem: the coupling, the probe, and the primitives.
#[derive(Debug, Clone, Copy)]
pub struct Problem<'a> {
    pub stiffness_n_per_m: f64,
    pub probe_m: DVec3,
    /// Where the proxy was last tick; used to warm-start when the previous dual cannot be reused.
    pub previous_proxy_m: Option<DVec3>,
    pub primitives: &'a [Primitive],
}

/// Why a problem was refused. Primitives are validated when they are built, so only the coupling can be bad.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SolveError {
    #[error("stiffness must be a finite number > 0 N/m, got {0}")]
    BadStiffness(f64),
    #[error("probe position must be three finite numbers (m), got {0:?}")]
    BadProbe([f64; 3]),
    #[error("previous proxy position must be three finite numbers (m), got {0:?}")]
    BadPreviousProxy([f64; 3]),
}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SolveStatus {
    /// The certified error bound is within the tolerance.
    Certified,
    /// The sweep or time budget ran out first; the answer is the best found, with its (honest) bound.
    BudgetExhausted,
    /// The bound stopped improving (2000 sweeps without halving) above the tolerance: the scene is at the limit
    /// of f64 precision for that tolerance. The answer is the best found, with its (honest) bound.
    Stalled,
}

/// The proxy position with its certificate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Solution {
    /// The proxy position (m).
    pub proxy_m: DVec3,
    /// The coupling force sent to the device, `k (proxy - probe)` (N).
    pub force_n: DVec3,
    /// O(N) passes over the primitives: the primal Newton method's passes plus the dual method's block
    /// sweeps (each is what `max_sweeps` limits).
    pub sweeps: u32,
    /// How many of `sweeps` were primal Newton passes.
    pub newton_passes: u32,
    /// Active-set attempts run.
    pub active_set_rounds: u32,
    /// Duality gap of the returned pair (J).
    pub gap_j: f64,
    /// Certified bound on the distance to the true minimiser, `sqrt(2 gap / k)` (m).
    pub error_bound_m: f64,
    pub status: SolveStatus,
}

/// A non-directed primitive as the solver sees it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Item {
    pub kind: PrimitiveKind,
    pub position_m: DVec3,
    pub direction: DVec3,
    pub strength_n: f64,
}

/// The solver and its workspace (STYLE.md item 3: allocate up front, `clear()` instead of rebuild).
#[derive(Debug, Clone)]
pub struct Solver {
    config: SolverConfig,
    items: Vec<Item>,
    dual: Vec<DVec3>,
    /// The active-set attempt writes here; it replaces `dual` only if it certifies a better point.
    candidate_dual: Vec<DVec3>,
    /// Whether `items` and `dual` hold the previous solve's values (false after `reset`).
    has_previous_dual: bool,
    active_set: active_set::Workspace,
    newton: newton::Workspace,
}

/// A primal point with its certificate.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    x: DVec3,
    gap_j: f64,
    bound_m: f64,
}

/// Most passes of the primal Newton attempt before the dual method takes over.
const NEWTON_MAX_PASSES: u32 = 100;

/// Sweeps without halving the bound after which a solve stops as [`SolveStatus::Stalled`]: the bound has reached
/// the floating-point floor of the scene and more sweeps cannot help.
const STALL_SWEEPS: u32 = 2000;

/// Scenes up to this many primitives are checked on the sweep schedule within a round; larger ones at the end
/// of each round.
const CHECK_EVERY_SWEEP_MAX_ITEMS: usize = 16;

/// A clock for solves without a time budget: never read.
struct NoClock;

impl Clock for NoClock {
    fn now_ns(&self) -> u64 {
        0
    }
}

impl Default for Solver {
    fn default() -> Self {
        Self::new(SolverConfig::default())
    }
}

impl Solver {
    pub fn new(config: SolverConfig) -> Self {
        Self::with_capacity(config, 16)
    }

    /// A solver whose workspace already holds `max_primitives`, so that no solve of that size allocates.
    pub fn with_capacity(config: SolverConfig, max_primitives: usize) -> Self {
        Self {
            config,
            items: Vec::with_capacity(max_primitives),
            dual: Vec::with_capacity(max_primitives),
            candidate_dual: Vec::with_capacity(max_primitives),
            has_previous_dual: false,
            active_set: active_set::Workspace::with_capacity(max_primitives),
            newton: newton::Workspace::with_capacity(max_primitives),
        }
    }

    pub fn config(&self) -> &SolverConfig {
        &self.config
    }

    pub fn config_mut(&mut self) -> &mut SolverConfig {
        &mut self.config
    }

    /// The force each non-directed primitive exerted on the proxy in the last solve, `-u_i` from its final
    /// dual (N), in the order the primitives were given with the directed ones skipped. They balance the
    /// coupling at the returned proxy within `k * error_bound_m`. Allocation-free.
    pub fn primitive_forces_n(&self) -> impl Iterator<Item = DVec3> + '_ {
        self.dual.iter().map(|u| -*u)
    }

    /// Forget the previous dual (the next solve starts cold or from `previous_proxy_m`).
    pub fn reset(&mut self) {
        self.has_previous_dual = false;
    }

    /// Solves with the sweep budget only (deterministic).
    pub fn solve(&mut self, problem: &Problem) -> Result<Solution, SolveError> {
        self.solve_inner(problem, &NoClock, false)
    }

    /// Solves with the sweep budget and the time budget `config.max_time_ns`, measured on `clock`.
    pub fn solve_with_clock(
        &mut self,
        problem: &Problem,
        clock: &dyn Clock,
    ) -> Result<Solution, SolveError> {
        self.solve_inner(problem, clock, true)
    }

    fn solve_inner(
        &mut self,
        problem: &Problem,
        clock: &dyn Clock,
        timed: bool,
    ) -> Result<Solution, SolveError> {
        let k = problem.stiffness_n_per_m;
        if !(k.is_finite() && k > 0.0) {
            return Err(SolveError::BadStiffness(k));
        }
        if !problem.probe_m.is_finite() {
            return Err(SolveError::BadProbe(problem.probe_m.to_array()));
        }
        if let Some(prev) = problem.previous_proxy_m {
            if !prev.is_finite() {
                return Err(SolveError::BadPreviousProxy(prev.to_array()));
            }
        }
        let start_ns = if timed { clock.now_ns() } else { 0 };
        let config = self.config;

        // y = probe + (sum of directed forces) / k; the rest become items.
        // Summed with compensation, so that y's rounding stays a few ulps however many directed forces there are.
        let mut directed = CompensatedSum::default();
        let mut directed_strength = 0.0;
        let mut directed_count = 0.0;
        // Build the items in place; the previous dual is reused when the kinds match one for one.
        let mut count = 0;
        let mut same_structure = self.config.warm_start_dual && self.has_previous_dual;
        let mut strength_sum = 0.0;
        for p in problem.primitives {
            if p.kind() == PrimitiveKind::Directed {
                directed.add(p.strength_n() * p.direction());
                directed_strength += p.strength_n();
                directed_count += 1.0;
                continue;
            }
            strength_sum += p.strength_n();
            if count < self.items.len() {
                // Field by field into the slot: an `Item` built on the stack and copied whole was read back
                // with wider loads than it was written with, which stalled the copy (store forwarding fails):
                // 4 % of a 10-primitive solve.
                let slot = &mut self.items[count];
                same_structure &= slot.kind == p.kind();
                slot.kind = p.kind();
                slot.position_m = p.position_m();
                slot.direction = p.direction();
                slot.strength_n = p.strength_n();
            } else {
                same_structure = false;
                self.items.push(Item {
                    kind: p.kind(),
                    position_m: p.position_m(),
                    direction: p.direction(),
                    strength_n: p.strength_n(),
                });
            }
            count += 1;
        }
        same_structure &= count == self.items.len() && count == self.dual.len();
        self.items.truncate(count);
        let directed = directed.value();
        let y = problem.probe_m + directed / k;
        let frame = Frame {
            y,
            k,
            // Each product s q rounds by eps/2 of s per coordinate (at most eps s in length); the compensated
            // sum adds 2 eps of the result and n eps^2 of the magnitudes (certificate.rs); the quotient by k and
            // the sum with the probe add eps/2 of their results each. Doubled for margin.
            // The 1-norms bound the lengths from above, without square roots.
            y_error_m: 2.0
                * f64::EPSILON
                * (problem.probe_m.abs().element_sum()
                    + (2.0 * directed.abs().element_sum()
                        + (1.0 + directed_count * f64::EPSILON) * directed_strength)
                        / k),
            strength_over_k_m: strength_sum / k,
        };
        // A reused dual is not projected here, though the previous tick's values may lie outside this tick's sets
        // (a weakened or tilted primitive): every use projects it first. A sweep projects each value it writes,
        // the primal method starts from zero, the certificate projects whatever it is given, and the one exit
        // that returns the warm start as it is (out of budget before any pass) projects it there.
        if !same_structure {
            if self.candidate_dual.capacity() < count {
                // Grown with the items, so that an exit that needs it (`least_energy`) never allocates.
                self.grow_candidate_dual(count);
            }
            self.dual.clear();
            match problem.previous_proxy_m {
                Some(x) => self
                    .dual
                    .extend(self.items.iter().map(|item| subgradient(item, x))),
                None => self.dual.resize(self.items.len(), DVec3::ZERO),
            }
        }
        self.has_previous_dual = true;

        let mut sweeps = 0u32;
        let mut rounds = 0u32;
        let mut total = self.dual.iter().copied().sum::<DVec3>();
        // The start (module header, "Budget exits"), `previous_proxy_m` or `y`: an exit without a certified
        // answer never returns a point of higher energy. Formed only at such an exit.
        let start_x = || problem.previous_proxy_m.unwrap_or(y);
        // The primal method's last accepted point, when it ran and did not certify (a candidate at such exits).
        let mut newton_x = None;
        // With primitives and a budget, at least one sweep runs before the first check, so the warm start is
        // not certified separately (it saves a gap evaluation per tick). Every exit below certifies what it
        // returns: `best` starts with an infinite bound, and the budget exit certifies the current dual.
        let mut best = if self.items.is_empty() {
            self.certify_dual(&frame, total)
        } else {
            Candidate {
                x: y - total / k,
                gap_j: f64::INFINITY,
                bound_m: f64::INFINITY,
            }
        };
        let mut best_at_sweep = 0u32;
        let mut retry_from_sweeps = false;
        let mut primal_fallback_done = false;
        let mut next_check = 1u32;
        let mut newton_passes = 0;
        let finish = |best: Candidate, sweeps, newton_passes, rounds, status| Solution {
            proxy_m: best.x,
            force_n: k * (best.x - problem.probe_m),
            sweeps,
            newton_passes,
            active_set_rounds: rounds,
            gap_j: best.gap_j,
            error_bound_m: best.bound_m,
            status,
        };
        let over_budget = |sweeps: u32| {
            sweeps >= config.max_sweeps
                || (timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns)
        };
        // With no pass allowed (or no time), the warm start is certified as it is, below.
        // Small warm-started scenes (the servo loop's usual tick: a surface and friction) are finished fastest
        // by a dual sweep or two from last tick's dual (the benchmark's exploration path: 0.2 us against 2 us
        // for the primal method); everything else starts with the primal method.
        let primal_first = config.primal_newton
            && !(same_structure && self.items.len() <= CHECK_EVERY_SWEEP_MAX_ITEMS);
        if primal_first && !self.items.is_empty() && !over_budget(sweeps) {
            let mut over_time =
                || timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns;
            let outcome = self.newton.solve(
                &self.items,
                &frame,
                problem.previous_proxy_m,
                newton_limits(&config, sweeps),
                &mut self.dual,
                &mut over_time,
            );
            sweeps += outcome.passes;
            newton_passes = outcome.passes;
            if !outcome.certified {
                newton_x = Some(outcome.x);
            }
            let checked = match outcome.certificate {
                Some(checked) => Some(checked),
                // Out of budget: the point and dual it reached are certified as they are.
                None if over_budget(sweeps) => Some(certify(
                    &self.items,
                    &self.dual,
                    &frame,
                    outcome.x,
                    config.tolerance_m,
                )),
                None => None,
            };
            if let Some(checked) = checked {
                best = Candidate {
                    x: outcome.x,
                    gap_j: checked.gap_j,
                    bound_m: checked.bound_m,
                };
                best_at_sweep = sweeps;
            }
            // The dual method goes on from the primal method's dual (feasible up to rounding; the sweeps project).
            // A certified answer returns at once, below, without it.
            if !outcome.certified {
                total = self.dual.iter().copied().sum::<DVec3>();
            }
        }
        loop {
            if best.bound_m <= config.tolerance_m {
                return Ok(finish(
                    best,
                    sweeps,
                    newton_passes,
                    rounds,
                    SolveStatus::Certified,
                ));
            }
            if over_budget(sweeps) {
                if !best.bound_m.is_finite() {
                    // Out of budget before any pass: the warm start, projected onto this tick's sets (it is
                    // what `primitive_forces_n` reports).
                    for (item, u) in self.items.iter().zip(self.dual.iter_mut()) {
                        *u = project(item, *u);
                    }
                    total = self.dual.iter().copied().sum::<DVec3>();
                    best = self.certify_dual(&frame, total);
                }
                let status = if best.bound_m <= config.tolerance_m {
                    SolveStatus::Certified
                } else {
                    best = self.least_energy(&frame, best, newton_x, start_x());
                    if best.bound_m <= config.tolerance_m {
                        SolveStatus::Certified
                    } else {
                        SolveStatus::BudgetExhausted
                    }
                };
                return Ok(finish(best, sweeps, newton_passes, rounds, status));
            }
            if sweeps - best_at_sweep >= STALL_SWEEPS {
                let best = self.least_energy(&frame, best, newton_x, start_x());
                let status = if best.bound_m <= config.tolerance_m {
                    SolveStatus::Certified
                } else {
                    SolveStatus::Stalled
                };
                return Ok(finish(best, sweeps, newton_passes, rounds, status));
            }
            let round_sweeps = config.sweeps_per_round.max(1);
            for sweep_in_round in 1..=round_sweeps {
                total = self.sweep(y, k, total, sweeps % 2 == 1);
                sweeps += 1;
                // A certificate costs about a sweep: check after sweeps 1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 15, ...
                // (at most a quarter of the sweeps are run past the one that met the tolerance), always at the
                // end of a round and when the budget is spent.
                // Large scenes check only at the end of a round: their sweeps rarely certify alone, and the
                // active-set attempt that follows does.
                let check_due =
                    sweeps >= next_check && self.items.len() <= CHECK_EVERY_SWEEP_MAX_ITEMS;
                if !check_due && sweep_in_round < round_sweeps && !over_budget(sweeps) {
                    continue;
                }
                next_check = sweeps + (sweeps / 4).max(1);
                let candidate = self.certify_dual(&frame, total);
                if candidate.bound_m < best.bound_m {
                    if candidate.bound_m < 0.5 * best.bound_m {
                        best_at_sweep = sweeps;
                    }
                    best = candidate;
                }
                if best.bound_m <= config.tolerance_m || over_budget(sweeps) {
                    break;
                }
            }
            if best.bound_m <= config.tolerance_m || over_budget(sweeps) || self.items.len() < 2 {
                continue;
            }
            rounds += 1;
            self.candidate_dual.clear();
            self.candidate_dual.extend_from_slice(&self.dual);
            // The guess starts from the best point so far, or, after an attempt from there did not improve on
            // it, from the sweeps' current point: the best point can sit where the guess is wrong (a proxy on a
            // friction point just under a plane, whose true minimiser is on the plane beside it), and starting
            // there again would repeat the same failed guess every round.
            let start = if retry_from_sweeps {
                y - total / k
            } else {
                best.x
            };
            let attempt = self.active_set.solve(
                &self.items,
                y,
                k,
                start,
                config.max_flips_per_round,
                &mut self.candidate_dual,
            );
            retry_from_sweeps = true;
            if let Some(x) = attempt {
                let candidate_total = self.candidate_dual.iter().copied().sum::<DVec3>();
                let checked = certify(
                    &self.items,
                    &self.candidate_dual,
                    &frame,
                    x,
                    config.tolerance_m,
                );
                let (gap, bound) = (checked.gap_j, checked.bound_m);
                if bound < best.bound_m {
                    if bound < 0.5 * best.bound_m {
                        best_at_sweep = sweeps;
                    }
                    best = Candidate {
                        x,
                        gap_j: gap,
                        bound_m: bound,
                    };
                    std::mem::swap(&mut self.dual, &mut self.candidate_dual);
                    total = candidate_total;
                    retry_from_sweeps = false;
                }
            }
            // A small warm scene that two active-set rounds could not finish gets the primal method once, from
            // the best point so far (the dual method can stall for its whole budget on a proxy held by a
            // friction point beside a plane; found by `the_bound_holds_on_a_plane_with_friction_tick_after_tick`).
            if !primal_first && !primal_fallback_done && config.primal_newton && rounds >= 2 {
                primal_fallback_done = true;
                let mut over_time =
                    || timed && clock.now_ns().saturating_sub(start_ns) >= config.max_time_ns;
                self.candidate_dual.clear();
                self.candidate_dual.extend_from_slice(&self.dual);
                let outcome = self.newton.solve(
                    &self.items,
                    &frame,
                    Some(best.x),
                    newton_limits(&config, sweeps),
                    &mut self.candidate_dual,
                    &mut over_time,
                );
                sweeps += outcome.passes;
                newton_passes += outcome.passes;
                if let Some(checked) = outcome.certificate {
                    if checked.bound_m < best.bound_m {
                        best = Candidate {
                            x: outcome.x,
                            gap_j: checked.gap_j,
                            bound_m: checked.bound_m,
                        };
                        best_at_sweep = sweeps;
                        std::mem::swap(&mut self.dual, &mut self.candidate_dual);
                        total = self.dual.iter().copied().sum::<DVec3>();
                    }
                }
            }
        }
    }

    /// One block-coordinate sweep over the dual; returns the new `U = sum u_i` (recomputed exactly).
    fn sweep(&mut self, y: DVec3, k: f64, mut total: DVec3, backwards: bool) -> DVec3 {
        let n = self.items.len();
        let w = self.config.relaxation;
        for step in 0..n {
            let i = if backwards { n - 1 - step } else { step };
            let item = &self.items[i];
            let old = self.dual[i];
            let others = total - old;
            let mut u = block_update(item, y, k, others);
            if w != 1.0 {
                u = project(item, old + w * (u - old));
            }
            self.dual[i] = u;
            total = others + u;
        }
        self.dual.iter().copied().sum()
    }

    /// The answer of an exit without a certified point (module header, "Budget exits"): of the start `start_x`,
    /// the best certified point `best` and the primal method's last accepted point `newton_x`, the one of least
    /// energy, a point replacing the one before it only where its energy is lower by more than both energies'
    /// rounding (so ties keep the start). Its bound is the smaller of the certificates with the current dual
    /// (or `best`'s own, for `best`) and with the exact subgradients at the point; `dual` keeps the dual of the
    /// bound returned. Allocation-free: the subgradients go to `candidate_dual`, sized for the items.
    #[cold]
    #[inline(never)]
    fn least_energy(
        &mut self,
        frame: &Frame,
        best: Candidate,
        newton_x: Option<DVec3>,
        start_x: DVec3,
    ) -> Candidate {
        let (mut x, mut energy_j, mut rounding_j) = {
            let (e, r) = energy(&self.items, frame, start_x);
            (start_x, e, r)
        };
        let mut is_best = best.x == start_x;
        for (candidate, from_best) in [(Some(best.x), true), (newton_x, false)] {
            let Some(candidate) = candidate.filter(|c| c.is_finite() && *c != x) else {
                continue;
            };
            let (e, r) = energy(&self.items, frame, candidate);
            if e + r < energy_j - rounding_j {
                (x, energy_j, rounding_j, is_best) = (candidate, e, r, from_best);
            }
        }
        let mut chosen = if is_best {
            best
        } else {
            self.certify_dual_at(frame, x)
        };
        self.candidate_dual.clear();
        self.candidate_dual
            .extend(self.items.iter().map(|item| subgradient(item, x)));
        let own = certify(
            &self.items,
            &self.candidate_dual,
            frame,
            x,
            self.config.tolerance_m,
        );
        if own.bound_m < chosen.bound_m {
            std::mem::swap(&mut self.dual, &mut self.candidate_dual);
            chosen = Candidate {
                x,
                gap_j: own.gap_j,
                bound_m: own.bound_m,
            };
        }
        chosen
    }

    #[cold]
    #[inline(never)]
    fn grow_candidate_dual(&mut self, count: usize) {
        let len = self.candidate_dual.len();
        self.candidate_dual.reserve(count.saturating_sub(len));
    }

    /// `x` with its certificate from the current dual.
    fn certify_dual_at(&self, frame: &Frame, x: DVec3) -> Candidate {
        let checked = certify(&self.items, &self.dual, frame, x, self.config.tolerance_m);
        Candidate {
            x,
            gap_j: checked.gap_j,
            bound_m: checked.bound_m,
        }
    }

    /// The primal point of the current dual and its certificate.
    fn certify_dual(&self, frame: &Frame, total: DVec3) -> Candidate {
        let x = frame.y - total / frame.k;
        let checked = certify(&self.items, &self.dual, frame, x, self.config.tolerance_m);
        Candidate {
            x,
            gap_j: checked.gap_j,
            bound_m: checked.bound_m,
        }
    }
}

/// The energy `P(x) = k/2 |x - y|^2 + sum_i s_i dist(x, C_i)` (J, the module header's, up to a constant) and a
/// bound on its rounding error, for comparing two points' energies. Each term is within a few eps of
/// `s_i (dist_i + |x - c_i|_1)` (the difference `x - c_i` is rounded per coordinate, a dot product with a unit
/// direction adds three eps), the sum of `N + 1` terms adds `N + 1` eps of the running sums, and `y`'s own
/// rounding (`frame.y_error_m`) moves the coupling term by at most `k |x - y| y_error`; the bound is eight
/// times that.
fn energy(items: &[Item], frame: &Frame, x: DVec3) -> (f64, f64) {
    let offset = x - frame.y;
    let mut energy_j = 0.5 * frame.k * offset.length_squared();
    let mut magnitude_j = energy_j;
    for item in items {
        let r = x - item.position_m;
        let distance_m = match item.kind {
            PrimitiveKind::Point => r.length(),
            PrimitiveKind::Line => (r - item.direction * item.direction.dot(r)).length(),
            PrimitiveKind::Plane => (-item.direction.dot(r)).max(0.0),
            PrimitiveKind::Directed => 0.0,
        };
        energy_j += item.strength_n * distance_m;
        magnitude_j += item.strength_n * (distance_m + r.abs().element_sum());
    }
    let rounding_j = 8.0 * (items.len() as f64 + 8.0) * f64::EPSILON * magnitude_j
        + 8.0 * frame.k * offset.length() * frame.y_error_m;
    (energy_j, rounding_j)
}

/// The primal Newton method's limits with `sweeps` of the sweep budget already spent.
fn newton_limits(config: &SolverConfig, sweeps: u32) -> newton::Limits {
    newton::Limits {
        tolerance_m: config.tolerance_m,
        max_passes: config
            .max_sweeps
            .saturating_sub(sweeps)
            .min(NEWTON_MAX_PASSES),
        screening: config.screening,
    }
}

/// The dual block update of one item (the module header's block sweeps): the exact minimiser of the dual over `u_i`
/// with the others' sum `others` fixed, `proj_{U_i}(k (y - c_i) - others)`. Used by the dual sweeps and by the
/// primal method's cold start.
#[inline]
pub(crate) fn block_update(item: &Item, y: DVec3, k: f64, others: DVec3) -> DVec3 {
    project(item, k * (y - item.position_m) - others)
}

/// Euclidean projection of `v` onto the dual set `U_i` of an item.
#[inline]
pub(crate) fn project(item: &Item, v: DVec3) -> DVec3 {
    let s = item.strength_n;
    match item.kind {
        PrimitiveKind::Point => clamp_length(v, s),
        PrimitiveKind::Line => {
            let q = item.direction;
            clamp_length(v - q * q.dot(v), s)
        }
        PrimitiveKind::Plane => {
            let q = item.direction;
            let t = (-q.dot(v)).max(0.0).min(s);
            -t * q
        }
        PrimitiveKind::Directed => DVec3::ZERO,
    }
}

#[inline]
fn clamp_length(v: DVec3, max: f64) -> DVec3 {
    let length = v.length();
    if length > max {
        if max > 0.0 {
            v * (max / length)
        } else {
            DVec3::ZERO
        }
    } else {
        v
    }
}

/// A subgradient of `s dist(x, C)` at `x` (zero on the kink): the dual that is exact if `x` is the answer and the
/// item is off its kink.
pub(crate) fn subgradient(item: &Item, x: DVec3) -> DVec3 {
    let s = item.strength_n;
    let r = x - item.position_m;
    match item.kind {
        PrimitiveKind::Point => r.normalize_or_zero() * s,
        PrimitiveKind::Line => {
            let q = item.direction;
            (r - q * q.dot(r)).normalize_or_zero() * s
        }
        PrimitiveKind::Plane => {
            if item.direction.dot(r) < 0.0 {
                -s * item.direction
            } else {
                DVec3::ZERO
            }
        }
        PrimitiveKind::Directed => DVec3::ZERO,
    }
}

#[cfg(test)]
mod tests;
