/* A simulated 3-DOF arm for the ports that have no motors: a point mass (the handle) held by a virtual hand that
 * moves it round a circle, plus the force the firmware applies. The same model as the built-in scene's arm in
 * voxhap (sims/scenes/explore.toml: mass 0.1 kg, damping 1 N s/m, hand 300 N/m and 3 N s/m, a 2 cm circle about
 * (0, 0, 0.02) m in the x-y plane every 3 s), so that `voxhap serve` with its built-in scene renders real contact.
 * float only; integrated with semi-implicit Euler in steps of at most 0.25 ms. */
#ifndef SIM_ARM_H
#define SIM_ARM_H

#include <stdint.h>

typedef struct {
    float position_m[3], velocity_m_per_s[3];
    float force_n[3]; /* what the motors apply now */
    float mass_kg, damping_n_s_per_m, hand_k_n_per_m, hand_c_n_s_per_m;
    float center_m[3], radius_m, period_s;
    float time_s; /* wraps every period, so float keeps its precision */
} sim_arm;

void sim_arm_init(sim_arm *arm);
/* Advances the arm by dt_s (long gaps are capped at 50 ms: the hand has moved on, the arm follows). */
void sim_arm_step(sim_arm *arm, float dt_s);

#endif
