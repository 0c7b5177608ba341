// Replies the robot owes the host (Acks, and a Params after RequestParams or at boot), kept in
// a fixed FIFO until the transmit ring has room for them. A reply is never dropped for want of
// room in the ring: it waits, and goes out before any later telemetry frame (the caller queues
// telemetry only while this store is empty, see docs/firmware.md "XBee link"). A reply is lost
// only when the store itself is full (a host sending commands faster than the uplink carries
// their Acks); that is counted (dropped(), saturating). Header-only, no heap; AVR and host.
#ifndef PROTOCOL_REPLIES_H
#define PROTOCOL_REPLIES_H

#include <stdint.h>

namespace proto {

struct Reply {
    enum Kind : uint8_t { kAck = 0, kParams = 1 };
    uint8_t kind;
    // kAck: the Ack's fields (protocol.json message Ack); unused for kParams
    uint8_t cmd_type;
    uint16_t cmd_seq;
    uint8_t result;
    uint8_t detail;
};

// N replies at most (1..255). Single-threaded: the main loop pushes and flushes.
template <uint8_t N>
class ReplyQueue {
    static_assert(N >= 1 && N <= 255, "N in 1..255");

public:
    ReplyQueue() : head_(0), count_(0), params_waiting_(false), dropped_(0) {}

    // An Ack owed to the host; false (nothing kept, dropped() + 1) when the store is full.
    bool ack(uint16_t cmd_seq, uint8_t cmd_type, uint8_t result, uint8_t detail) {
        Reply r;
        r.kind = Reply::kAck;
        r.cmd_type = cmd_type;
        r.cmd_seq = cmd_seq;
        r.result = result;
        r.detail = detail;
        return push(r);
    }

    // A Params frame owed to the host. The sink builds it when it sends it, so it carries the
    // values of that moment; while one waits unsent, another request is answered by it (true,
    // nothing added). False (dropped() + 1) when the store is full.
    bool params() {
        if (params_waiting_) return true;
        Reply r;
        r.kind = Reply::kParams;
        r.cmd_type = 0;
        r.cmd_seq = 0;
        r.result = 0;
        r.detail = 0;
        if (!push(r)) return false;
        params_waiting_ = true;
        return true;
    }

    // Hands the replies to sink.send(const Reply&) in the order they were owed, while it takes
    // them; the first it refuses (false: no room now, nothing sent) and those after it stay.
    // Returns true when none is left.
    template <class Sink>
    bool flush(Sink& sink) {
        while (count_ != 0) {
            const Reply& r = buf_[head_];
            if (!sink.send(r)) return false;
            if (r.kind == Reply::kParams) params_waiting_ = false;
            head_ = static_cast<uint8_t>(head_ + 1u == N ? 0u : head_ + 1u);
            --count_;
        }
        return true;
    }

    bool empty() const { return count_ == 0; }
    uint8_t size() const { return count_; }
    static uint8_t capacity() { return N; }
    // Replies lost because the store was full (saturating).
    uint16_t dropped() const { return dropped_; }

private:
    bool push(const Reply& r) {
        if (count_ == N) {
            if (dropped_ != 0xFFFFu) ++dropped_;
            return false;
        }
        uint16_t i = static_cast<uint16_t>(head_) + count_;
        if (i >= N) i = static_cast<uint16_t>(i - N);
        buf_[i] = r;
        ++count_;
        return true;
    }

    Reply buf_[N];
    uint8_t head_;
    uint8_t count_;
    bool params_waiting_;
    uint16_t dropped_;
};

}  // namespace proto

#endif  // PROTOCOL_REPLIES_H
