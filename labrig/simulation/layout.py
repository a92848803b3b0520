"""Where the simulator's kernels keep things: the columns of the candidates' parameter
table, the rows of a block's working array (the population kernel's lanes), the builds'
mode bits, and the closed loop's table of affine pieces. Constants only, so every kernel
module can import them without a cycle."""

#: kernel parameter columns: R, L, J, B, K, then the effects', then the back-EMF constant
#: (labrig.model.simulate writes them)
C_D, C_U0, C_ASYM, C_VMAX, C_TC, C_TS, C_A, C_TD, C_KE = range(5, 14)
#: then the run's initial state per candidate (labrig.model.start): the current, the motor
#: speed, the output shaft's offset from the position the first samples read, and where the
#: motor sits in a backlash gap (a fraction of the half gap, -1..1, from the output) (all 0:
#: the run starts at rest where its first samples say, the gap centred)
C_I0, C_W0, C_TH0, C_GAP0 = range(14, 18)
#: the parameter table's width
N_COLS = 18

#: the open-loop input map the population kernel applies itself, in this order (every
#: simulator's order): offset, asymmetry, dead zone, asymmetric dead zone, the gain Ka,
#: the armature rail; each as the effect's own formula (labrig.model.effects), so the
#: result is the number numpy gives
MAP_COLUMNS = ("u0_v", "k", "d_v", "dpos_v", "dneg_v", "vmax_v")
M_U0, M_K, M_D, M_DP, M_DN, M_VMAX = range(6)
#: smaller populations go one candidate at a time (:func:`_candidate`): for a few lanes
#: the block's per-sample overhead costs more than the vector loop saves
SMALL = 8
#: candidates per block of the population kernel: a multiple of the SIMD width whose
#: state (a few arrays of BLOCK doubles) stays in the first-level cache
BLOCK = 64


#: where a loop's drive is, for the error e it amplifies: in the dead zone, in the linear
#: part for a positive or negative error, or on the rail (+ or -)
G_DEAD, G_POS, G_NEG, G_RAILP, G_RAILN = range(5)
#: the loop table's slots, one exact zero-order hold per affine piece of the drive: flat
#: (dead zone or rail: the loop is open and the drive constant), linear for + and -
#: errors (an asymmetry gives them different gains), and the same inside a backlash gap
#: (the pot does not move: no position feedback)
S_FLAT, S_POS, S_NEG, S_POS_GAP, S_NEG_GAP = range(5)
N_SLOTS = 5
#: a slot's row: Ad (a22 - 1 in place of a22), g_old, g_new, g_f
#: (slot 0's T_OK: 1 when the candidate's pieces are exact, 0 when every sample is
#: sub-stepped: a current-mode drive's quasi-static armature, see
#: labrig.model.simulate._loop_table)
T_A, T_GO, T_GN, T_GF, T_OK = 0, 9, 12, 15, 18
SLOT_W = 19


# Rows of a block's working array: coefficients, state and flags of each candidate, one
# row of BLOCK lanes each. One array with rows a constant BLOCK apart lets the compiler
# prove that the lanes' loads and stores never overlap, so it vectorises without checks.
(R_A00, R_A01, R_A02, R_A10, R_A11, R_A12, R_A20, R_A21, R_A22M1, R_GN0, R_GN1, R_GN2, R_GO0,
 R_GO1, R_GO2, R_GF0, R_GF1, R_GF2, R_TC, R_GAP, R_FRIC, R_I, R_W, R_TH, R_PL, R_ACC, R_FLAG,
 R_I0, R_W0, R_TH0, R_PL0, R_SNEW, R_SOLD, R_RR, R_KK, R_TS, R_E1, R_E2, R_MAP) = range(39)
#: then the input map's six parameters, and a measured current's squared residual (added
#: to the sum after the lanes: a test inside them made the compiler form it in every build)
R_DI = R_MAP + 6
N_ROWS = R_DI + 1
#: a closed loop with its input map (:func:`_sweep_loop`) adds rows saying the lane's
#: input switches inside the sample (a fractional delay), the slot its drive was last in
#: (-1: none yet, or a lane sub-stepped throughout) and that slot's row of the loop table
#: (Ad, g_old, g_new, g_f): the update's coefficients, changed only where the piece does;
#: and theta / N of the lane's state, which the sample before computed (one division a
#: sample, not two: the lanes' divisions are what their vectors wait for)
R_DLY = N_ROWS
R_SLOT = N_ROWS + 1
R_CUR = N_ROWS + 2
R_XN = R_CUR + T_OK
#: and the piece (G_*) the lane's drive is in, that piece's constant drive (the loop's
#: mapped s_new) and the side of a backlash gap the pot is on (1 pressed at its lower end,
#: -1 at its upper, 2 inside, 0 no gap), as the last sample the lanes computed in full
#: found them: a steady input's next sample starts where the last one ended, in the same
#: piece (:data:`STEADY`)
R_G = R_XN + 1
R_CN = R_XN + 2
R_SIDE = R_XN + 3
N_ROWS_LOOP = R_SIDE + 1

#: the terms a block's update needs (bits of ``_sweep``'s mode; one build per mode used);
#: MOVING: friction, but no lane of the block is at rest this sample: the build without
#: the stuck rotor's current decay and its divisions (nothing can be held)
FEEDBACK, DELAY, FRICTION, PLAY, MOVING = 1, 2, 4, 8, 16
#: a closed loop with its map (the loop's own builds, labrig.simulation.loop_kernel):
#: STEADY: the input did not change and no lane was redone alone in the sample before,
#: so every lane's drive starts in the piece it ended in (no need to find it again);
#: NO_KINK: no lane has a dead zone or an asymmetry (the map is the gain and the rail),
#: and every lane a backlash gap (the builds of backlash alone)
STEADY, NO_KINK = 32, 64
#: the modes built: the short update, a delay, Coulomb friction, each alone or in a linear
#: closed loop, and every term in open and in closed loop (the feedback bit also says how
#: a stuck rotor's drive is formed: through the loop, or the input itself); each with
#: friction also as MOVING. Others take every term (the compiler did not vectorise some)
MODES = (0, FRICTION, FEEDBACK, DELAY, FEEDBACK | DELAY, FEEDBACK | FRICTION,
         DELAY | FRICTION | PLAY, FEEDBACK | DELAY | FRICTION | PLAY)
