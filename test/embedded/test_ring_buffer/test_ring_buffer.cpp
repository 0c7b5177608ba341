// Ring buffers on the (simulated) ATmega2560: FIFO order, capacity N - 1, wrap-around, and the
// single-producer/single-consumer contract under real preemption (a timer ISR as the other
// side), plus the XBee transmit path's drop-and-count when the ring is full.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <unity.h>

#include "ring_buffer.h"
#include "xbee.h"

void setUp() {}
void tearDown() {}

static void test_fifo_order_and_capacity() {
    RingBuffer<8> rb;
    TEST_ASSERT_TRUE(rb.empty());
    TEST_ASSERT_EQUAL_UINT16(7, rb.capacity());
    for (uint8_t i = 0; i < 7; ++i) TEST_ASSERT_TRUE(rb.push(static_cast<uint8_t>(10 + i)));
    TEST_ASSERT_FALSE(rb.push(99));  // full: nothing written
    TEST_ASSERT_EQUAL_UINT16(7, rb.used());
    TEST_ASSERT_EQUAL_UINT16(0, rb.free_slots());
    uint8_t b = 0;
    for (uint8_t i = 0; i < 7; ++i) {
        TEST_ASSERT_TRUE(rb.pop(&b));
        TEST_ASSERT_EQUAL_UINT8(10 + i, b);
    }
    TEST_ASSERT_FALSE(rb.pop(&b));
    TEST_ASSERT_EQUAL_UINT8(16, b);  // unchanged by the failed pop
}

static void test_wrap_around_many_times() {
    RingBuffer<16> rb;
    uint8_t next_in = 0, next_out = 0;
    for (uint16_t round = 0; round < 500; ++round) {
        uint8_t n_in = static_cast<uint8_t>(1 + round % 15);
        for (uint8_t i = 0; i < n_in; ++i)
            if (rb.push(next_in)) ++next_in;
        TEST_ASSERT_EQUAL_UINT16(rb.capacity() - rb.used(), rb.free_slots());
        uint8_t n_out = static_cast<uint8_t>(1 + (round * 7) % 15);
        uint8_t b;
        for (uint8_t i = 0; i < n_out && rb.pop(&b); ++i) {
            TEST_ASSERT_EQUAL_UINT8(next_out, b);
            ++next_out;
        }
    }
}

static void test_sizes_2_and_256() {
    RingBuffer<2> small;
    TEST_ASSERT_TRUE(small.push(1));
    TEST_ASSERT_FALSE(small.push(2));
    RingBuffer<256> big;
    uint16_t n = 0;
    while (big.push(static_cast<uint8_t>(n))) ++n;
    TEST_ASSERT_EQUAL_UINT16(255, n);
    uint8_t b;
    for (uint16_t i = 0; i < 255; ++i) {
        TEST_ASSERT_TRUE(big.pop(&b));
        TEST_ASSERT_EQUAL_UINT8(static_cast<uint8_t>(i), b);
    }
    TEST_ASSERT_TRUE(big.empty());
}

static void test_push_block_wraps_and_is_all_or_nothing() {
    RingBuffer<16> rb;
    uint8_t b;
    for (uint8_t i = 0; i < 11; ++i) rb.push(i);
    for (uint8_t i = 0; i < 11; ++i) rb.pop(&b);  // head and tail at 11: a block must wrap
    uint8_t blk[15];
    for (uint8_t i = 0; i < sizeof blk; ++i) blk[i] = static_cast<uint8_t>(100 + i);
    TEST_ASSERT_FALSE(rb.push_block(blk, 16));  // more than the capacity: nothing written
    TEST_ASSERT_TRUE(rb.empty());
    TEST_ASSERT_TRUE(rb.push_block(blk, 10));
    TEST_ASSERT_FALSE(rb.push_block(blk, 6));   // 5 free: all or nothing
    TEST_ASSERT_EQUAL_UINT16(10, rb.used());
    for (uint8_t i = 0; i < 10; ++i) {
        TEST_ASSERT_TRUE(rb.pop(&b));
        TEST_ASSERT_EQUAL_UINT8(100 + i, b);
    }
    TEST_ASSERT_FALSE(rb.pop(&b));
}

// ---- ISR as producer (like USART RX) and as consumer (like UDRE) ----
static RingBuffer<16> g_to_main;
static RingBuffer<16> g_to_isr;
static volatile uint8_t g_isr_next = 0, g_isr_expect = 0;
static volatile uint16_t g_isr_pushed = 0, g_isr_popped = 0, g_isr_errors = 0;
static volatile bool g_isr_on = false;

ISR(TIMER2_COMPA_vect) {
    if (!g_isr_on) return;
    if (g_to_main.push(g_isr_next)) {
        g_isr_next = static_cast<uint8_t>(g_isr_next + 1);
        g_isr_pushed = g_isr_pushed + 1;
    }
    uint8_t b;
    if (g_to_isr.pop(&b)) {
        if (b != g_isr_expect) g_isr_errors = g_isr_errors + 1;
        g_isr_expect = static_cast<uint8_t>(b + 1);
        g_isr_popped = g_isr_popped + 1;
    }
}

static void test_spsc_against_a_preempting_isr() {
    // Timer2 CTC every 160 cycles: it preempts the main loop inside push()/pop()
    TCCR2A = _BV(WGM21);
    OCR2A = 19;
    TCCR2B = _BV(CS21);  // clk/8
    TIMSK2 = _BV(OCIE2A);
    g_isr_on = true;
    sei();
    uint8_t expect = 0, out = 0;
    uint16_t got = 0, sent = 0;
    uint32_t spins = 0;
    while ((got < 3000 || sent < 3000) && spins < 2000000ul) {
        ++spins;
        uint8_t b;
        if (got < 3000 && g_to_main.pop(&b)) {
            TEST_ASSERT_EQUAL_UINT8(expect, b);  // no loss, no duplicate, no torn byte
            expect = static_cast<uint8_t>(b + 1);
            ++got;
        }
        if (sent < 3000 && g_to_isr.push(out)) {
            out = static_cast<uint8_t>(out + 1);
            ++sent;
        }
        if ((spins & 63) == 0)
            for (volatile uint8_t d = 0; d < 200; ++d) {  // slow consumer: the ring fills up
            }
    }
    while (g_isr_popped < 3000 && spins < 2000000ul) ++spins;
    g_isr_on = false;
    TIMSK2 = 0;
    TEST_ASSERT_EQUAL_UINT16(3000, got);
    TEST_ASSERT_EQUAL_UINT16(3000, g_isr_popped);
    TEST_ASSERT_EQUAL_UINT16(0, g_isr_errors);
}

static void test_xbee_write_drops_whole_frames_and_never_blocks() {
    xbee_init();
    sei();
    uint8_t frame[200];
    for (uint16_t i = 0; i < sizeof frame; ++i) frame[i] = static_cast<uint8_t>(i);
    uint16_t drops0 = xbee_counters().tx_drops;
    TEST_ASSERT_TRUE(xbee_write(frame, sizeof frame));
    uint16_t free_after_first = xbee_tx_free();
    TEST_ASSERT_FALSE(xbee_write(frame, sizeof frame));  // does not fit: dropped whole
    TEST_ASSERT_EQUAL_UINT16(drops0 + 1, xbee_counters().tx_drops);
    TEST_ASSERT_TRUE(xbee_tx_free() >= free_after_first);  // nothing partial was queued
    xbee_count_drop();  // a frame the application chose not to queue (telemetry behind a reply)
    TEST_ASSERT_EQUAL_UINT16(drops0 + 2, xbee_counters().tx_drops);
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_fifo_order_and_capacity);
    RUN_TEST(test_wrap_around_many_times);
    RUN_TEST(test_sizes_2_and_256);
    RUN_TEST(test_push_block_wraps_and_is_all_or_nothing);
    RUN_TEST(test_spsc_against_a_preempting_isr);
    RUN_TEST(test_xbee_write_drops_whole_frames_and_never_blocks);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
