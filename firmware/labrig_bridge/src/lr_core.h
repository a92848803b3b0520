/* labrig bridge core: command handling, waveform generation, sampling scheduler and
 * safety (hard output limit, host-silence watchdog, 0 V at reset/stop/end). */
#ifndef LR_CORE_H
#define LR_CORE_H
#include <stdint.h>
#include "lr_proto.h"

#ifdef __cplusplus
extern "C" {
#endif

/* DAC word that gives 0 V after the bipolar stage (12-bit MCP4822 at gain 2x: 2048). */
#ifndef LR_DAC_ZERO
#define LR_DAC_ZERO 2048
#endif
/* Firmware hard limit, counts either side of LR_DAC_ZERO: 1064 = +-2.598 V on the
 * +-5 V stage: times the SA150D's gain of 5 it stays inside the amplifier's 13 V rail
 * (12.99 V), 4 % above the default rig's 2.5 V host limit so a calibration gain of a few
 * percent still fits. */
#ifndef LR_FW_LIMIT_COUNTS
#define LR_FW_LIMIT_COUNTS 1064
#endif
#ifndef LR_WATCHDOG_MS_DEFAULT
#define LR_WATCHDOG_MS_DEFAULT 500
#endif
/* What HELLO tells the host about the build (protocol 2): the rig's hardware layer, the
 * clock whose divisors are the exact sample rates, the output word's bits, and for the
 * H-bridge its drive flags, encoder decoding and PWM bits. The MS150 bridge's defaults. */
#ifndef LR_RIG_KIND
#define LR_RIG_KIND 1            /* 1 MS150 (MCP4822 + analog sensors), 2 H-bridge + encoder */
#endif
#ifndef LR_TIMER_HZ
#define LR_TIMER_HZ 2000000UL    /* Timer1 at 16 MHz / 8 */
#endif
#ifndef LR_DAC_BITS
#define LR_DAC_BITS 12
#endif
#ifndef LR_ADC_CHANNELS
#define LR_ADC_CHANNELS 3
#endif
#ifndef LR_RIG_FLAGS
#define LR_RIG_FLAGS 0           /* bit0 IN1/IN2 drive, bit1 brake off phase, bit2 current sense,
                                    bit3 index pulse input (INDEX messages) */
#endif
#ifndef LR_DECODING
#define LR_DECODING 0            /* encoder decoding 1, 2 or 4; 0 no encoder */
#endif
#ifndef LR_PWM_BITS
#define LR_PWM_BITS 0
#endif
/* 1: a closed-loop run is a PD on the encoder count computed here at every sample (the
 * H-bridge rig); 0: the loop is analog, outside the board (the MS150's patch panel) */
#ifndef LR_DIGITAL_LOOP
#define LR_DIGITAL_LOOP 0
#endif
/* a digital loop's reference words are counts around this word */
#define LR_REF_ZERO 32768
#define LR_RING 32  /* samples buffered between the ADC ISR and the sender (power of 2) */
#define LR_MIN_RATE_HZ 50

enum { LR_STATE_IDLE = 0, LR_STATE_CONFIGURED = 1, LR_STATE_RUNNING = 2, LR_STATE_FINISHING = 3 };

typedef struct {
    uint32_t samples_sent, rx_overruns, watchdog_trips, sample_overruns, ring_overflows;
} lr_counters_t;

/* fw_id: in flash on the AVR (PSTR), in memory elsewhere */
void lr_core_init(uint8_t board_id, const char *fw_id, uint16_t max_rate_hz);
void lr_core_tick(void);                                    /* timer ISR */
void lr_core_sample_done(uint16_t tacho, uint16_t pos, uint16_t ref); /* ADC ISR */
void lr_core_poll(void);                                    /* main loop */
void lr_core_send_hello(void);
void lr_core_rx_overrun(void);                              /* UART ISR saw DOR/FE */
uint8_t lr_core_state(void);
uint16_t lr_core_reference(void);
uint32_t lr_core_sample_index(void);                        /* the next sample's index (ISRs) */                           /* digital loop: this sample's reference word */
uint16_t lr_core_dac_word(void);                            /* last word written */
const lr_counters_t *lr_core_counters(void);
const lr_decoder_t *lr_core_decoder(void);

#ifdef __cplusplus
}
#endif
#endif
