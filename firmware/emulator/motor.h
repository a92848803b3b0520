/* The H-bridge rig's plant in the labrig emulator: a supply switched onto a DC gear motor
 * by the bridge the chip's pins command, the motor's friction and the gear's play, and a
 * quadrature encoder. Written from the physics here, independent of labrig's simulator. */
#ifndef MOTOR_H
#define MOTOR_H
#include <stdint.h>

typedef struct {
    double R, L, J, B, K;        /* armature ohm, H; kg m^2 at the motor; N m s/rad; N m/A */
    double supply;               /* V */
    double drop;                 /* V lost across the bridge's two conducting switches */
    double dead_fwd, dead_rev;   /* the bridge's dead zone each way, as volts of the average:
                                    it swallows that share of the supply at the start of each
                                    pulse (turn-on delay), so a narrow pulse never arrives */
    double Tc;                   /* Coulomb friction at the motor, N m */
    double Ts;                   /* static friction (break-away) at the motor, N m; <= Tc: none */
    double N;                    /* gear ratio */
    double backlash;             /* play of the gear at the output shaft, rad (0: none) */
    int encoder_on_output;       /* 1: the encoder is on the output shaft (sees the play) */
    double lines;                /* encoder cycles per turn of the shaft it sits on */
    int in1_in2;                 /* 0: PWM + DIR (EN pin PWM'd), 1: IN1/IN2 */
    int brake;                   /* PWM + DIR: the driver brakes in its off phase (else coasts) */
} motor_params_t;

typedef struct {
    motor_params_t p;
    double i, w, theta_m, theta_out;
    int stuck;                   /* held by static friction */
    int64_t edge;                /* encoder edge index: floor(angle * 4 * lines / 2 pi) */
} motor_t;

/* what the bridge's inputs do during one step: the share of it the motor is driven
 * (0..1), the direction of the drive (+1/-1), and whether the rest brakes (else coasts) */
typedef struct {
    double driven;
    int dir;
    int brake;
} bridge_step_t;

void motor_init(motor_t *m, const motor_params_t *p);
void motor_step(motor_t *m, const bridge_step_t *b, double dt);
/* the encoder's edge index now (4 per cycle, whatever the chip decodes) */
int64_t motor_edge(const motor_t *m);
#endif
