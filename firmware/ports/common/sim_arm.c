#include "sim_arm.h"

#include <math.h>

#define TWO_PI 6.28318530718f

static void hand(const sim_arm *a, float t, float p[3], float v[3]) {
    float w = TWO_PI / a->period_s, c = cosf(w * t), s = sinf(w * t);
    p[0] = a->center_m[0] + a->radius_m * c;
    p[1] = a->center_m[1] + a->radius_m * s;
    p[2] = a->center_m[2];
    v[0] = -a->radius_m * w * s;
    v[1] = a->radius_m * w * c;
    v[2] = 0.0f;
}

void sim_arm_init(sim_arm *a) {
    float v[3];
    int i;
    a->mass_kg = 0.1f;
    a->damping_n_s_per_m = 1.0f;
    a->hand_k_n_per_m = 300.0f;
    a->hand_c_n_s_per_m = 3.0f;
    a->center_m[0] = 0.0f;
    a->center_m[1] = 0.0f;
    a->center_m[2] = 0.02f;
    a->radius_m = 0.02f;
    a->period_s = 3.0f;
    a->time_s = 0.0f;
    hand(a, 0.0f, a->position_m, v);
    for (i = 0; i < 3; i++) {
        a->velocity_m_per_s[i] = v[i];
        a->force_n[i] = 0.0f;
    }
}

void sim_arm_step(sim_arm *a, float dt_s) {
    if (dt_s > 0.05f) {
        dt_s = 0.05f;
    }
    while (dt_s > 0.0f) {
        float h = dt_s > 0.00025f ? 0.00025f : dt_s;
        float hp[3], hv[3];
        int i;
        a->time_s += h;
        if (a->time_s >= a->period_s) {
            a->time_s -= a->period_s;
        }
        hand(a, a->time_s, hp, hv);
        for (i = 0; i < 3; i++) {
            float f = a->hand_k_n_per_m * (hp[i] - a->position_m[i]) +
                      a->hand_c_n_s_per_m * (hv[i] - a->velocity_m_per_s[i]) -
                      a->damping_n_s_per_m * a->velocity_m_per_s[i] + a->force_n[i];
            a->velocity_m_per_s[i] += h * f / a->mass_kg;
            a->position_m[i] += h * a->velocity_m_per_s[i];
        }
        dt_s -= h;
    }
}
