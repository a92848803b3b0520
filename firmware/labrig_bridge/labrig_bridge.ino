// labrig bridge firmware: the AVR HAL for the portable core in src/.
// Uno/Nano (ATmega328P) and Mega 2560 from this one source, one hardware layer per rig
// chosen at build: RIG=ms150 (src/hal_ms150.inc, the default) or RIG=hbridge
// (src/hal_hbridge.inc). Build with firmware/Makefile (Debian avr-gcc + arduino-core-avr)
// or the Arduino IDE (the MS150 layer unless LR_RIG_KIND is defined 2).
//
// No ISR waits on hardware, so the UART receive interrupt is never held off for long.
#include <Arduino.h>
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>
#include <avr/eeprom.h>
#include <avr/wdt.h>
#include "src/lr_core.h"
#include "src/lr_hal.h"

#define FW_VERSION "2.4.1"
#ifndef BAUD
#define BAUD 500000UL   // make BAUD=250000 builds another (the host's --baud must match)
#endif

#if defined(__AVR_ATmega2560__)
#define BOARD_ID 2
#define BOARD_NAME "mega"
#define RX_VECT USART0_RX_vect
#define UDRE_VECT USART0_UDRE_vect
#elif defined(__AVR_ATmega328P__)
#if defined(ARDUINO_AVR_NANO)
#define BOARD_ID 3
#define BOARD_NAME "nano"
#else
#define BOARD_ID 1
#define BOARD_NAME "uno"
#endif
#define RX_VECT USART_RX_vect
#define UDRE_VECT USART_UDRE_vect
#else
#error "labrig bridge: Uno/Nano (ATmega328P) or Mega 2560 only"
#endif

// Highest rate the firmware accepts: 3200 Hz measured gap-free under simavr, 4000 Hz
// not (docs/hardware.md); 2500 Hz leaves a margin.
#ifndef LR_MAX_RATE_HZ
#define LR_MAX_RATE_HZ 2500
#endif

// ---- UART: interrupt-driven rings; a receive overrun (DOR) or framing error is counted
static volatile uint8_t rx_buf[64], rx_head, rx_tail;
static volatile uint8_t tx_buf[256], tx_head, tx_tail;   // uint8_t indices wrap at 256

ISR(RX_VECT)
{
    uint8_t st = UCSR0A;
    uint8_t c = UDR0;
    if (st & (_BV(DOR0) | _BV(FE0))) lr_core_rx_overrun();
    uint8_t next = (uint8_t)((rx_head + 1) & 63);
    if (next == rx_tail) { lr_core_rx_overrun(); return; }
    rx_buf[rx_head] = c;
    rx_head = next;
}

ISR(UDRE_VECT)
{
    if (tx_head == tx_tail) { UCSR0B &= (uint8_t)~_BV(UDRIE0); return; }
    UDR0 = tx_buf[tx_tail++];
}

extern "C" int hal_rx_read(void)
{
    if (rx_head == rx_tail) return -1;
    uint8_t c = rx_buf[rx_tail];
    rx_tail = (uint8_t)((rx_tail + 1) & 63);
    return c;
}

extern "C" uint16_t hal_tx_free(void) { return (uint16_t)(255 - (uint8_t)(tx_head - tx_tail)); }

extern "C" void hal_tx_write(const uint8_t *d, uint16_t n)
{
    while (n--) {
        while ((uint8_t)(tx_head + 1) == tx_tail) { }   // main loop only: the UDRE ISR drains
        tx_buf[tx_head++] = *d++;
        UCSR0B |= _BV(UDRIE0);
    }
}

#if LR_RIG_KIND == 2
#include "src/hal_hbridge.inc"
#else
#include "src/hal_ms150.inc"
#endif

// The E-stop input, on both rigs: D7 (Uno/Nano PD7, Mega PH4), pulled up; a normally-
// closed switch to GND holds it low, and pressing it or breaking its wire lets it rise.
#if defined(__AVR_ATmega2560__)
#define ESTOP_DDR DDRH
#define ESTOP_PORT PORTH
#define ESTOP_PIN PINH
#define ESTOP_BIT 4
#else
#define ESTOP_DDR DDRD
#define ESTOP_PORT PORTD
#define ESTOP_PIN PIND
#define ESTOP_BIT 7
#endif
extern "C" uint8_t hal_estop(void) { return (ESTOP_PIN & _BV(ESTOP_BIT)) ? 1 : 0; }

// the board's id: EEPROM bytes 0-1 "LR", 2-5 the id (u32 LE); anything else: none yet
extern "C" uint32_t hal_id_read(void)
{
    if (eeprom_read_byte((const uint8_t *)0) != 'L' || eeprom_read_byte((const uint8_t *)1) != 'R')
        return 0;
    return eeprom_read_dword((const uint32_t *)2);
}

extern "C" void hal_id_write(uint32_t id)
{
    eeprom_update_dword((uint32_t *)2, id);
    eeprom_update_byte((uint8_t *)0, 'L');   // the mark last: a reset mid-write leaves none
    eeprom_update_byte((uint8_t *)1, 'R');
}

extern "C" uint32_t hal_millis(void) { return millis(); }
extern "C" uint8_t hal_lock(void) { uint8_t s = SREG; cli(); return s; }
extern "C" void hal_unlock(uint8_t s) { SREG = s; }

// The AVR's own watchdog: a main loop that stops polling (a hang, a runaway write)
// resets the chip within this, and a reset puts the output at 0 V (setup's first act).
// Off for a Nano with the old bootloader (make BOARD=nano HW_WATCHDOG=0): it does not
// clear the watchdog after the reset and loops in its own start-up.
#ifndef LR_HW_WATCHDOG
#define LR_HW_WATCHDOG 1
#endif

void setup()
{
    rig_setup();   // the output at 0 V first
#if LR_HW_WATCHDOG
    MCUSR = 0;     // a watchdog reset leaves the watchdog on at 16 ms: off until set up
    wdt_disable();
#endif
    ESTOP_DDR &= (uint8_t)~_BV(ESTOP_BIT);   // the E-stop: input, pulled up
    ESTOP_PORT |= _BV(ESTOP_BIT);

    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / 8UL / BAUD - 1);            // 3: exact 500 kbaud at 16 MHz
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);                    // 8N1
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    // the id in flash, read by the core with pgm_read_byte (LR_TEXT)
    lr_core_init(BOARD_ID, PSTR("labrig-fw " FW_VERSION " " BOARD_NAME " " RIG_NAME), LR_MAX_RATE_HZ);
    sei();
    lr_core_send_hello();   // unsolicited; a host that opened late asks with HELLO_REQ
#if LR_HW_WATCHDOG
    wdt_enable(WDTO_250MS);
#endif
}

void loop()
{
    lr_core_poll();
#if LR_HW_WATCHDOG
    wdt_reset();
#endif
}
