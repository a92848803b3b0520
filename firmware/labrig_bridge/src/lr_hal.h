/* The small hardware layer the core needs. The sketch implements it for AVR
 * (labrig_bridge.ino); the host unit tests implement it with plain memory. */
#ifndef LR_HAL_H
#define LR_HAL_H
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Start a DAC update of the output channel (non-blocking; called from the timer ISR
 * and from the main loop with interrupts off). The word is already limit-checked. */
void hal_dac_write(uint16_t word);
/* Start one acquisition (tacho, pos, ref); the HAL calls lr_core_sample_done() from
 * its ADC interrupt when all three conversions are in. Never blocks. */
void hal_adc_start(void);
/* The encoder's count now (a digital position loop's feedback; called from the sample
 * interrupt, where the count cannot change under it). 0 on a rig without an encoder. */
int32_t hal_position(void);
/* The index pulse (the H-bridge rig's encoder): 1 when a pulse came since the last call,
 * with the count latched at its rising edge, the sample it came before and the pulses
 * since hal_index_reset(); 0 when none came (always, on a rig without one). Main loop. */
uint8_t hal_index_take(int32_t *count, uint32_t *sample, uint16_t *pulses);
/* Forget the pulses so far (START, interrupts off). */
void hal_index_reset(void);
/* Undecodable encoder jumps since reset, saturating at 65535 (0 without an encoder). */
uint16_t hal_encoder_faults(void);
/* The E-stop input (Uno/Nano D7, Mega D7, pulled up): 1 when it reads high (the
 * normally-closed switch open: pressed, or its wire broken). ISR-safe. */
uint8_t hal_estop(void);
/* The board's id in non-volatile memory (the AVR's EEPROM), 0 when none was given; and
 * keep one (main loop, not while a run plays: an EEPROM write blocks for ~20 ms). */
uint32_t hal_id_read(void);
void hal_id_write(uint32_t id);
/* Next received byte, or -1 if none waiting. */
int hal_rx_read(void);
/* Bytes of space in the transmit queue; hal_tx_write() blocks only beyond that. */
uint16_t hal_tx_free(void);
void hal_tx_write(const uint8_t *data, uint16_t len);
uint32_t hal_millis(void);
/* Sampling timer at rate_hz (validated by the core), first tick one period later. */
void hal_timer_start(uint16_t rate_hz);
void hal_timer_stop(void);
/* Critical sections around data shared with the ISRs. */
uint8_t hal_lock(void);
void hal_unlock(uint8_t saved);

#ifdef __cplusplus
}
#endif
#endif
