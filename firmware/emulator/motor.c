#include "motor.h"
#include <math.h>

void motor_init(motor_t *m, const motor_params_t *p)
{
    m->p = *p;
    m->i = m->w = m->theta_m = m->theta_out = 0.0;
    m->stuck = 1;
    m->edge = 0;
}

static double sgn(double x) { return (x > 0) - (x < 0); }

void motor_step(motor_t *m, const bridge_step_t *b, double dt)
{
    const motor_params_t *p = &m->p;
    double emf = p->K * m->w;
    /* the terminals: the supply (less the switches' drop) while driven; while off, shorted
     * (brake: slow decay) or, coasting, the current returns to the supply through the
     * diodes (fast decay) until it is gone, then the terminals float at the back-EMF */
    double v_on = b->dir * (p->supply - p->drop);
    double v_off;
    if (b->brake) v_off = 0.0;
    else v_off = m->i != 0.0 ? -sgn(m->i) * (p->supply + 1.4) : emf;
    double v = b->driven * v_on + (1.0 - b->driven) * v_off;
    double i_new = (m->i + dt / p->L * (v - emf)) / (1.0 + dt * p->R / p->L);   /* implicit in R */
    if (!b->brake && b->driven < 1.0 && (i_new * m->i < 0.0 || (m->i == 0.0 && b->driven == 0.0)))
        i_new = 0.0;   /* the diodes block: a coasting current ends at zero */
    m->i = i_new;

    double torque = p->K * m->i - p->B * m->w;
    double ts = p->Ts > p->Tc ? p->Ts : p->Tc;
    if (m->stuck) {
        if (fabs(p->K * m->i) <= ts) { m->w = 0.0; goto shaft; }
        m->stuck = 0;
    }
    {
        double w_new = m->w + dt / p->J * (torque - p->Tc * sgn(m->w != 0.0 ? m->w : torque));
        if (m->w != 0.0 && w_new * m->w <= 0.0) {        /* it stops within this step */
            w_new = 0.0;
            m->stuck = fabs(p->K * m->i) <= ts;
        }
        m->w = w_new;
    }
shaft:
    m->theta_m += m->w * dt;
    /* the output shaft follows the gear through its play (its inertia is in J) */
    double geared = m->theta_m / p->N, half = 0.5 * p->backlash;
    if (geared - m->theta_out > half) m->theta_out = geared - half;
    else if (m->theta_out - geared > half) m->theta_out = geared + half;
    double angle = p->encoder_on_output ? m->theta_out : m->theta_m;
    m->edge = (int64_t)floor(angle * 4.0 * p->lines / (2.0 * M_PI));
}

int64_t motor_edge(const motor_t *m) { return m->edge; }
