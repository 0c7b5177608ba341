#include "xbee.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"
#include "ring_buffer.h"

namespace {
RingBuffer<256> g_rx;
RingBuffer<256> g_tx;
volatile uint16_t g_rx_overflows;
volatile uint16_t g_rx_errors;
uint16_t g_tx_drops;  // main loop only
}  // namespace

ISR(USART2_RX_vect) {
    uint8_t st = UCSR2A;
    uint8_t b = UDR2;  // reading UDR2 clears RXC2: this ISR cannot re-enter (next byte in 87 us)
    sei();             // so encoder edges may interrupt the rest of it
    if ((st & (_BV(FE2) | _BV(DOR2))) && g_rx_errors != 0xFFFFu) g_rx_errors = g_rx_errors + 1;
    if (!g_rx.push(b) && g_rx_overflows != 0xFFFFu) g_rx_overflows = g_rx_overflows + 1;
}

// UDRE is level-triggered (set while UDR2 is empty), so this ISR masks itself (UDRIE2 off)
// before it re-enables interrupts: encoder edges then wait only for the prologue. Nothing else
// can set UDRIE2 meanwhile -- xbee_write() runs in the main loop, which cannot run until this
// ISR returns -- so the ring keeps a single consumer.
ISR(USART2_UDRE_vect) {
    UCSR2B &= static_cast<uint8_t>(~_BV(UDRIE2));
    sei();
    uint8_t b;
    if (g_tx.pop(&b)) {
        UDR2 = b;
        cli();
        UCSR2B |= _BV(UDRIE2);  // more may follow; an empty ring is found on the next entry
    }
}

void xbee_init() {
    // U2X before UBRR: the hardware does not care, but simavr computes its byte time when UBRR
    // is written, with the U2X bit of that moment; the other order made it receive at half the
    // baud rate and overrun its 64-byte input FIFO on bursts of more than ~120 bytes.
    UCSR2A = XBEE_U2X ? _BV(U2X2) : 0;
    UBRR2 = XBEE_UBRR;
    UCSR2C = _BV(UCSZ21) | _BV(UCSZ20);  // 8N1
    UCSR2B = _BV(RXEN2) | _BV(TXEN2) | _BV(RXCIE2);
}

bool xbee_write(const uint8_t* p, uint16_t n) {
    if (!g_tx.push_block(p, n)) {
        if (g_tx_drops != 0xFFFFu) ++g_tx_drops;
        return false;
    }
    uint8_t sreg = SREG;
    cli();  // UCSR2B is also written by the UDRE ISR
    UCSR2B |= _BV(UDRIE2);
    SREG = sreg;
    return true;
}

bool xbee_read(uint8_t* b) { return g_rx.pop(b); }

uint16_t xbee_tx_free() { return g_tx.free_slots(); }

XbeeCounters xbee_counters() {
    XbeeCounters c;
    uint8_t sreg = SREG;
    cli();
    c.rx_overflows = g_rx_overflows;
    c.rx_errors = g_rx_errors;
    SREG = sreg;
    c.tx_drops = g_tx_drops;
    return c;
}
