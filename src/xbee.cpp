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

ISR(XBEE_RX_VECT) {
    uint8_t st = XBEE_UCSRA;
    uint8_t b = XBEE_UDR;  // reading UDR clears RXC: this ISR cannot re-enter (next byte in 87 us)
    sei();                 // so encoder edges may interrupt the rest of it
    if ((st & (_BV(XBEE_FE_BIT) | _BV(XBEE_DOR_BIT))) && g_rx_errors != 0xFFFFu) g_rx_errors = g_rx_errors + 1;
    if (!g_rx.push(b) && g_rx_overflows != 0xFFFFu) g_rx_overflows = g_rx_overflows + 1;
}

// UDRE is level-triggered (set while UDR is empty), so this ISR masks itself (UDRIE off)
// before it re-enables interrupts: encoder edges then wait only for the prologue. Nothing else
// can set UDRIE meanwhile -- xbee_write() runs in the main loop, which cannot run until this
// ISR returns -- so the ring keeps a single consumer.
ISR(XBEE_UDRE_VECT) {
    XBEE_UCSRB &= static_cast<uint8_t>(~_BV(XBEE_UDRIE_BIT));
    sei();
    uint8_t b;
    if (g_tx.pop(&b)) {
        XBEE_UDR = b;
        cli();
        XBEE_UCSRB |= _BV(XBEE_UDRIE_BIT);  // more may follow; an empty ring is found on the next entry
    }
}

void xbee_init() {
    // U2X before UBRR: the hardware does not care, but simavr computes its byte time when UBRR
    // is written, with the U2X bit of that moment; the other order made it receive at half the
    // baud rate and overrun its 64-byte input FIFO on bursts of more than ~120 bytes.
    XBEE_UCSRA = XBEE_U2X ? _BV(XBEE_U2X_BIT) : 0;
    XBEE_UBRRN = XBEE_UBRR;
    XBEE_UCSRC = XBEE_UCSRC_8N1;
    XBEE_UCSRB = _BV(XBEE_RXEN_BIT) | _BV(XBEE_TXEN_BIT) | _BV(XBEE_RXCIE_BIT);
}

void xbee_count_drop() {
    if (g_tx_drops != 0xFFFFu) ++g_tx_drops;
}

bool xbee_write(const uint8_t* p, uint16_t n) {
    if (!g_tx.push_block(p, n)) {
        xbee_count_drop();
        return false;
    }
    uint8_t sreg = SREG;
    cli();  // UCSRB is also written by the UDRE ISR
    XBEE_UCSRB |= _BV(XBEE_UDRIE_BIT);
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
