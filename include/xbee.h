// XBee link on USART2 (TX2 = pin 16, RX2 = pin 17), 8N1 at XBEE_BAUD (board.h).
// Interrupt-driven rings: RX 256 bytes (RX ISR produces, main loop consumes), TX 256 bytes
// (main loop produces, UDRE ISR consumes). Transmit never blocks: a frame that does not fit
// whole is dropped and counted. The application keeps its replies until they fit (it checks
// xbee_tx_free() first) and counts a frame it chooses not to queue with xbee_count_drop().
#ifndef FW_XBEE_H
#define FW_XBEE_H

#include <stdint.h>

struct XbeeCounters {
    uint16_t rx_overflows;   // bytes lost because the RX ring was full (saturating)
    uint16_t rx_errors;      // framing / data-overrun errors flagged by the USART (saturating)
    uint16_t tx_drops;       // frames not queued: xbee_write() found no room, or xbee_count_drop() (saturating)
};

void xbee_init();
// Queues n bytes as one unit; false (nothing queued, tx_drops + 1) when they do not fit.
bool xbee_write(const uint8_t* p, uint16_t n);
// Counts one frame the application did not queue (tx_drops + 1, saturating).
void xbee_count_drop();
// One received byte; false when none is waiting.
bool xbee_read(uint8_t* b);
XbeeCounters xbee_counters();
uint16_t xbee_tx_free();

#endif  // FW_XBEE_H
