// labrig bridge firmware: the AVR HAL for the portable core in src/.
// Uno (ATmega328P) and Mega 2560 from this one source. Build with firmware/Makefile
// (Debian avr-gcc + arduino-core-avr) or the Arduino IDE.
//
// Timing: Timer1 (CTC) ticks at the sample rate; its ISR updates the DAC (SPI driven by
// the SPI interrupt) and starts the ADC; the ADC interrupt walks the three channels.
// No ISR waits on hardware, so the UART receive interrupt is never held off for long.
#include <Arduino.h>
#include <avr/io.h>
#include <avr/interrupt.h>
#include <util/atomic.h>
#include "src/lr_core.h"
#include "src/lr_hal.h"

#define FW_VERSION "1.1.0"
#define BAUD 500000UL

#if defined(__AVR_ATmega2560__)
#define BOARD_ID 2
#define BOARD_NAME "mega"
#define CS_BIT PB0     // D53 (SS)
#define SCK_BIT PB1    // D52
#define MOSI_BIT PB2   // D51
#define RX_VECT USART0_RX_vect
#define UDRE_VECT USART0_UDRE_vect
#elif defined(__AVR_ATmega328P__)
#define BOARD_ID 1
#define BOARD_NAME "uno"
#define CS_BIT PB2     // D10 (SS)
#define SCK_BIT PB5    // D13
#define MOSI_BIT PB3   // D11
#define RX_VECT USART_RX_vect
#define UDRE_VECT USART_UDRE_vect
#else
#error "labrig bridge: Uno (ATmega328P) or Mega 2560 only"
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

// ---- MCP4822 on SPI. Channel B holds mid-scale; the bipolar stage amplifies A - B, so
// both channels at their power-up 0 V give 0 V out before the firmware has run.
static volatile uint8_t spi_state, spi_lo, spi_pending;
static volatile uint16_t spi_next;

static void spi_begin_word(uint16_t cmd)
{
    PORTB &= (uint8_t)~_BV(CS_BIT);
    spi_lo = (uint8_t)cmd;
    spi_state = 1;
    SPDR = (uint8_t)(cmd >> 8);
}

ISR(SPI_STC_vect)
{
    if (spi_state == 1) {
        spi_state = 2;
        SPDR = spi_lo;
    } else {
        PORTB |= _BV(CS_BIT);                            // rising CS latches the word (LDAC tied low)
        spi_state = 0;
        if (spi_pending) { spi_pending = 0; spi_begin_word(spi_next); }
    }
}

// 0x1000: channel A, gain 2x (0..4.095 V), active
extern "C" void hal_dac_write(uint16_t w)
{
    uint16_t cmd = (uint16_t)(0x1000 | (w & 0x0FFF));
    uint8_t s = SREG;
    cli();
    if (spi_state) { spi_next = cmd; spi_pending = 1; }   // latest word wins
    else spi_begin_word(cmd);
    SREG = s;
}

static void spi_blocking_word(uint16_t cmd)
{
    PORTB &= (uint8_t)~_BV(CS_BIT);
    SPDR = (uint8_t)(cmd >> 8);
    while (!(SPSR & _BV(SPIF))) { }
    SPDR = (uint8_t)cmd;
    while (!(SPSR & _BV(SPIF))) { }
    PORTB |= _BV(CS_BIT);
}

// ---- ADC: A0 tacho, A1 output pot, A2 input pot/reference; AVcc reference
static volatile uint8_t adc_ch;
static volatile uint16_t adc_val[3];

extern "C" void hal_adc_start(void)
{
    adc_ch = 0;
    ADMUX = _BV(REFS0) | 0;
    ADCSRA |= _BV(ADSC);
}

ISR(ADC_vect)
{
    uint16_t v = ADC;
    uint8_t ch = adc_ch;
    adc_val[ch] = v;
    if (++ch < 3) {
        adc_ch = ch;
        ADMUX = (uint8_t)(_BV(REFS0) | ch);
        ADCSRA |= _BV(ADSC);
    } else {
        lr_core_sample_done(adc_val[0], adc_val[1], adc_val[2]);
    }
}

// ---- Timer1: CTC at the sample rate (prescaler 8: 2 MHz count, so rates dividing 2 MHz are exact)
extern "C" void hal_timer_start(uint16_t rate_hz)
{
    uint8_t s = SREG;
    cli();
    TCCR1A = 0;
    TCCR1B = 0;
    TCNT1 = 0;
    OCR1A = (uint16_t)(F_CPU / 8UL / rate_hz - 1);
    TIFR1 = _BV(OCF1A);
    TIMSK1 = _BV(OCIE1A);
    TCCR1B = _BV(WGM12) | _BV(CS11);
    SREG = s;
}

extern "C" void hal_timer_stop(void)
{
    TIMSK1 = 0;
    TCCR1B = 0;
}

ISR(TIMER1_COMPA_vect) { lr_core_tick(); }

extern "C" uint32_t hal_millis(void) { return millis(); }
extern "C" uint8_t hal_lock(void) { uint8_t s = SREG; cli(); return s; }
extern "C" void hal_unlock(uint8_t s) { SREG = s; }

void setup()
{
    // DAC first: 0 V at reset before anything else runs
    DDRB |= _BV(CS_BIT) | _BV(SCK_BIT) | _BV(MOSI_BIT);  // CS is SS: output keeps SPI master
    PORTB |= _BV(CS_BIT);
    SPCR = _BV(SPE) | _BV(MSTR);                           // mode 0
    SPSR = _BV(SPI2X);                                     // 8 MHz (MCP4822: 20 MHz max)
    spi_blocking_word(0x9000 | LR_DAC_ZERO);               // B: mid-scale, the bipolar offset
    spi_blocking_word(0x1000 | LR_DAC_ZERO);               // A: mid-scale = 0 V out
    SPCR |= _BV(SPIE);

    hal_timer_stop();                                      // undo the core's PWM setup of Timer1
    ADCSRB = 0;
    ADMUX = _BV(REFS0);
    // ADC clock 16 MHz/64 = 250 kHz: 52 us per conversion, 3 channels in ~170 us
    ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1);
    DIDR0 = 0x07;                                          // no digital input buffers on A0..A2

    UCSR0A = _BV(U2X0);
    UBRR0 = (uint16_t)(F_CPU / 8UL / BAUD - 1);            // 3: exact 500 kbaud at 16 MHz
    UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);                    // 8N1
    UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);

    lr_core_init(BOARD_ID, "labrig-fw " FW_VERSION " " BOARD_NAME, LR_MAX_RATE_HZ);
    sei();
    lr_core_send_hello();   // unsolicited; a host that opened late asks with HELLO_REQ
}

void loop()
{
    lr_core_poll();
}
