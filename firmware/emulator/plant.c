#include "plant.h"
#include <math.h>

static double urand(plant_t *s)
{
    /* xorshift64*: deterministic noise for a given seed */
    s->rng ^= s->rng >> 12; s->rng ^= s->rng << 25; s->rng ^= s->rng >> 27;
    return ((s->rng * 0x2545F4914F6CDD1DULL) >> 11) * (1.0 / 9007199254740992.0);
}

static double gauss(plant_t *s)
{
    double u1 = urand(s), u2 = urand(s);
    if (u1 < 1e-300) u1 = 1e-300;
    return sqrt(-2.0 * log(u1)) * cos(2.0 * M_PI * u2);
}

void plant_init(plant_t *s, const plant_params_t *p)
{
    s->p = *p;
    s->i = s->w = s->theta_m = s->u = 0.0;
    s->rng = p->seed ? p->seed : 0x9E3779B97F4A7C15ULL;
}

static double pos_clean(const plant_t *s) { return s->p.Kpot * s->theta_m / s->p.N + s->p.pos_offset; }

void plant_step(plant_t *s, double dt)
{
    const plant_params_t *p = &s->p;
    double vin = s->u;
    if (p->closed)   /* the analog loop sees the pot on the output shaft, not its offset */
        vin = p->kp * (s->u - p->Kpot * s->theta_m / p->N) - p->kv * p->Kt * s->w;
    double v = p->Ka * vin;
    if (v > p->Vmax) v = p->Vmax;
    if (v < -p->Vmax) v = -p->Vmax;
    /* semi-implicit armature: stable for any dt against the fast L/R pole */
    s->i = (s->i + dt / p->L * (v - p->K * s->w)) / (1.0 + dt * p->R / p->L);
    double torque = p->K * s->i;
    double w_new = s->w + dt / p->J * (torque - p->B * s->w);
    if (p->Tc > 0) {
        double fr = p->Tc * dt / p->J;
        if (fabs(w_new) <= fr && fabs(torque) <= p->Tc) w_new = 0.0;   /* stuck */
        else w_new -= (w_new > 0 ? fr : -fr);
    }
    s->w = w_new;
    s->theta_m += s->w * dt;
}

double plant_tacho_v(plant_t *s) { return s->p.Kt * s->w + s->p.noise_tacho * gauss(s); }
double plant_pos_v(plant_t *s) { return pos_clean(s) + s->p.noise_pos * gauss(s); }
