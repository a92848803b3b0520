/* DC servo plant of the labrig emulator (motor + amplifier + gearbox + sensors). */
#ifndef PLANT_H
#define PLANT_H
#include <stdint.h>

typedef struct {
    double R, L, J, B, K;        /* armature ohm, H; kg m^2; N m s/rad; N m/A = V s/rad */
    double Ka, Vmax;             /* amplifier gain (armature V per bridge V) and rail */
    double N;                    /* gear ratio, motor turns per output turn */
    double Kt;                   /* tacho V per rad/s (motor shaft) */
    double Kpot, pos_offset;     /* output pot V per rad and offset V */
    double noise_tacho, noise_pos; /* rms V */
    double Tc;                   /* Coulomb friction N m (0: none) */
    int closed;                  /* 0 open loop, 1 position loop with tacho feedback */
    double kp, kv;               /* closed loop: amp input = kp*(ref - pos) - kv*tacho */
    uint64_t seed;
} plant_params_t;

typedef struct {
    plant_params_t p;
    double i, w, theta_m;        /* state: current, motor speed, motor angle */
    double u;                    /* bridge output volts (open: amp input; closed: reference) */
    uint64_t rng;
} plant_t;

void plant_init(plant_t *s, const plant_params_t *p);
void plant_step(plant_t *s, double dt);
double plant_tacho_v(plant_t *s);   /* with noise */
double plant_pos_v(plant_t *s);     /* with noise */
#endif
