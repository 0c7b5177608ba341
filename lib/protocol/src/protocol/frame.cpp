#include <protocol/crc16.h>
#include <protocol/frame.h>
#include <protocol/wire.h>

namespace proto {

uint16_t encode_frame(uint8_t type, uint16_t seq, const uint8_t* payload, uint8_t payload_len,
                      uint8_t* out, uint16_t out_cap) {
    if (payload_len > kMaxPayload) return 0;
    if (out_cap < wire_size(payload_len)) return 0;
    // The body is assembled on the stack (kMaxBody bytes), then COBS-encoded into out.
    uint8_t body[kMaxBody];
    uint16_t n = 0;
    body[n++] = kVersion;
    body[n++] = type;
    put_u16(body + n, seq);
    n = static_cast<uint16_t>(n + 2);
    for (uint8_t i = 0; i < payload_len; ++i) body[n++] = payload[i];
    put_u16(body + n, crc16(body, n));
    n = static_cast<uint16_t>(n + 2);
    out[0] = 0;
    uint16_t enc = cobs_encode(body, n, out + 1, static_cast<uint16_t>(out_cap - 2));
    if (enc == 0) return 0;
    out[1 + enc] = 0;
    return static_cast<uint16_t>(enc + 2);
}

void Decoder::reset() {
    n_ = 0;
    overflow_ = false;
    frame_.version = 0;
    frame_.type = 0;
    frame_.seq = 0;
    frame_.payload = buf_;
    frame_.len = 0;
    error_ = kErrNone;
    error_hdr_ = false;
    err_type_ = 0;
    err_seq_ = 0;
    frames_ok_ = 0;
    crc_errors_ = 0;
    bad_frames_ = 0;
}

Decoder::Status Decoder::feed(uint8_t byte) {
    if (byte != 0) {
        if (n_ < sizeof buf_) {
            buf_[n_++] = byte;
        } else {
            overflow_ = true;  // keep discarding until the next delimiter
        }
        return kNone;
    }
    if (n_ == 0 && !overflow_) return kNone;  // empty block between delimiters
    Status s = finish();
    n_ = 0;
    overflow_ = false;
    return s;
}

Decoder::Status Decoder::finish() {
    error_hdr_ = false;
    if (overflow_) {
        error_ = kErrTooLong;
        sat_inc(&bad_frames_);
        return kError;
    }
    int16_t len = cobs_decode(buf_, n_, buf_, sizeof buf_);
    if (len < 0) {
        error_ = kErrCobs;
        sat_inc(&bad_frames_);
        return kError;
    }
    if (len < kHeaderBytes + kCrcBytes) {
        error_ = kErrTooShort;
        sat_inc(&bad_frames_);
        return kError;
    }
    if (len > static_cast<int16_t>(kMaxBody)) {
        error_ = kErrTooLong;
        sat_inc(&bad_frames_);
        return kError;
    }
    uint16_t body = static_cast<uint16_t>(len - kCrcBytes);
    uint16_t want = get_u16(buf_ + body);
    err_type_ = buf_[1];
    err_seq_ = get_u16(buf_ + 2);
    if (crc16(buf_, body) != want) {
        error_ = kErrCrc;
        error_hdr_ = true;
        sat_inc(&crc_errors_);
        return kError;
    }
    if (buf_[0] != kVersion) {
        error_ = kErrVersion;
        error_hdr_ = true;
        sat_inc(&bad_frames_);
        return kError;
    }
    frame_.version = buf_[0];
    frame_.type = buf_[1];
    frame_.seq = err_seq_;
    frame_.payload = buf_ + kHeaderBytes;
    frame_.len = static_cast<uint8_t>(body - kHeaderBytes);
    error_ = kErrNone;
    sat_inc(&frames_ok_);
    return kFrame;
}

}  // namespace proto
