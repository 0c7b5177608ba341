// Native Unity tests of proto::ReplyQueue (lib/protocol/src/protocol/replies.h): the replies the
// firmware owes the host wait for room in the transmit ring instead of being dropped, go out in
// the order they were owed, and before telemetry; only a full store loses one, counted.
#include <stdint.h>
#include <unity.h>

#include <protocol/frame.h>
#include <protocol/messages.h>
#include <protocol/replies.h>

using namespace proto;

void setUp() {}
void tearDown() {}

// A transmit ring of `room` bytes that takes a reply only when its whole frame fits (as the
// firmware's sink does with xbee_tx_free()); records what it took.
struct RingSink {
    uint16_t room;
    uint16_t params_value;  // what a Params built now would carry
    uint8_t n;
    Reply sent[64];
    uint16_t params_values[64];

    explicit RingSink(uint16_t room_bytes) : room(room_bytes), params_value(0), n(0) {}

    static uint16_t bytes(const Reply& r) {
        return wire_size(r.kind == Reply::kParams ? static_cast<uint8_t>(Params::kSize)
                                                  : static_cast<uint8_t>(Ack::kSize));
    }
    bool send(const Reply& r) {
        uint16_t b = bytes(r);
        if (b > room) return false;
        room = static_cast<uint16_t>(room - b);
        params_values[n] = params_value;
        sent[n++] = r;
        return true;
    }
};

static const uint16_t kAckWire = 14;  // docs/firmware.md: an Ack is 14 bytes on the wire

static void test_an_ack_frame_is_14_bytes_on_the_wire() {
    TEST_ASSERT_EQUAL_UINT16(kAckWire, wire_size(Ack::kSize));
    uint8_t out[kMaxWire];
    Ack a;
    a.cmd_seq = 0xFFFF;
    a.cmd_type = 0xFF;
    a.result = 0xFF;
    a.detail = 0xFF;
    TEST_ASSERT_EQUAL_UINT16(kAckWire, encode_message(a, 0xFFFF, out, sizeof out));
}

static void test_replies_that_do_not_fit_wait_and_go_in_order() {
    ReplyQueue<8> q;
    TEST_ASSERT_TRUE(q.empty());
    for (uint8_t i = 0; i < 5; ++i) TEST_ASSERT_TRUE(q.ack(100 + i, 16, 0, 255));
    RingSink full(2 * kAckWire + 3);  // room for two Acks only
    TEST_ASSERT_FALSE(q.flush(full));
    TEST_ASSERT_EQUAL_UINT8(2, full.n);
    TEST_ASSERT_EQUAL_UINT8(3, q.size());
    TEST_ASSERT_EQUAL_UINT16(100, full.sent[0].cmd_seq);
    TEST_ASSERT_EQUAL_UINT16(101, full.sent[1].cmd_seq);
    RingSink none(kAckWire - 1);  // no room at all: nothing sent, nothing lost
    TEST_ASSERT_FALSE(q.flush(none));
    TEST_ASSERT_EQUAL_UINT8(0, none.n);
    TEST_ASSERT_EQUAL_UINT8(3, q.size());
    RingSink room(255);
    TEST_ASSERT_TRUE(q.flush(room));
    TEST_ASSERT_TRUE(q.empty());
    TEST_ASSERT_EQUAL_UINT8(3, room.n);
    for (uint8_t i = 0; i < 3; ++i) {
        TEST_ASSERT_EQUAL_UINT8(Reply::kAck, room.sent[i].kind);
        TEST_ASSERT_EQUAL_UINT16(102 + i, room.sent[i].cmd_seq);
        TEST_ASSERT_EQUAL_UINT8(16, room.sent[i].cmd_type);
        TEST_ASSERT_EQUAL_UINT8(255, room.sent[i].detail);
    }
    TEST_ASSERT_EQUAL_UINT16(0, q.dropped());
}

static void test_params_follow_their_ack_and_carry_the_values_when_sent() {
    ReplyQueue<4> q;
    q.ack(7, 17, 0, 255);  // RequestParams' Ack
    q.params();
    RingSink tight(kAckWire);  // the Ack fits, the Params waits
    tight.params_value = 1;
    TEST_ASSERT_FALSE(q.flush(tight));
    TEST_ASSERT_EQUAL_UINT8(1, tight.n);
    TEST_ASSERT_EQUAL_UINT8(1, q.size());
    RingSink later(255);
    later.params_value = 2;  // a command handled meanwhile changed a parameter
    q.ack(8, 18, 0, 255);    // its Ack comes after the Params owed before it
    TEST_ASSERT_TRUE(q.flush(later));
    TEST_ASSERT_EQUAL_UINT8(2, later.n);
    TEST_ASSERT_EQUAL_UINT8(Reply::kParams, later.sent[0].kind);
    TEST_ASSERT_EQUAL_UINT16(2, later.params_values[0]);
    TEST_ASSERT_EQUAL_UINT16(8, later.sent[1].cmd_seq);
}

static void test_a_params_waiting_answers_a_second_request() {
    ReplyQueue<8> q;
    q.params();
    q.ack(1, 17, 0, 255);
    TEST_ASSERT_TRUE(q.params());  // one Params unsent: it answers this request too
    TEST_ASSERT_EQUAL_UINT8(2, q.size());
    RingSink room(255);
    TEST_ASSERT_TRUE(q.flush(room));
    TEST_ASSERT_EQUAL_UINT8(2, room.n);
    TEST_ASSERT_TRUE(q.params());  // sent: a new request is owed a new Params
    TEST_ASSERT_EQUAL_UINT8(1, q.size());
}

static void test_a_full_store_drops_and_counts_saturating() {
    ReplyQueue<3> q;
    for (uint8_t i = 0; i < 3; ++i) TEST_ASSERT_TRUE(q.ack(i, 16, 0, 255));
    TEST_ASSERT_FALSE(q.ack(3, 16, 0, 255));
    TEST_ASSERT_FALSE(q.params());
    TEST_ASSERT_EQUAL_UINT16(2, q.dropped());
    RingSink room(255);
    TEST_ASSERT_TRUE(q.flush(room));
    TEST_ASSERT_EQUAL_UINT8(3, room.n);
    TEST_ASSERT_EQUAL_UINT16(2, room.sent[2].cmd_seq);  // the kept ones, not the dropped one
    TEST_ASSERT_TRUE(q.params());  // the refused Params did not leave a stale "waiting" mark
    TEST_ASSERT_EQUAL_UINT8(1, q.size());
    ReplyQueue<1> s;
    s.ack(0, 16, 0, 255);
    for (uint32_t i = 0; i < 70000ul; ++i) s.ack(1, 16, 0, 255);
    TEST_ASSERT_EQUAL_UINT16(0xFFFF, s.dropped());
}

static void test_the_fifo_wraps_around() {
    ReplyQueue<5> q;
    uint16_t next_in = 0, next_out = 0;
    for (uint8_t round = 0; round < 40; ++round) {
        uint8_t k = static_cast<uint8_t>(1 + round % 5);
        for (uint8_t i = 0; i < k && q.size() < 5; ++i) TEST_ASSERT_TRUE(q.ack(next_in++, 16, 0, 255));
        RingSink some(static_cast<uint16_t>(kAckWire * (round % 4)));
        q.flush(some);
        for (uint8_t i = 0; i < some.n; ++i) TEST_ASSERT_EQUAL_UINT16(next_out++, some.sent[i].cmd_seq);
    }
    RingSink room(255);
    q.flush(room);
    for (uint8_t i = 0; i < room.n; ++i) TEST_ASSERT_EQUAL_UINT16(next_out++, room.sent[i].cmd_seq);
    TEST_ASSERT_EQUAL_UINT16(next_in, next_out);
    TEST_ASSERT_EQUAL_UINT16(0, q.dropped());
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_an_ack_frame_is_14_bytes_on_the_wire);
    RUN_TEST(test_replies_that_do_not_fit_wait_and_go_in_order);
    RUN_TEST(test_params_follow_their_ack_and_carry_the_values_when_sent);
    RUN_TEST(test_a_params_waiting_answers_a_second_request);
    RUN_TEST(test_a_full_store_drops_and_counts_saturating);
    RUN_TEST(test_the_fifo_wraps_around);
    return UNITY_END();
}
