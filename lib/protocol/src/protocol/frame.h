// Frame layer: body = version u8, type u8, seq u16 LE, payload, CRC-16/CCITT-FALSE u16 LE over
// everything before it; on the wire: 0x00, COBS(body), 0x00. Fixed buffers, no heap.
#ifndef PROTOCOL_FRAME_H
#define PROTOCOL_FRAME_H

#include <stdint.h>
#include <protocol/cobs.h>
#include <protocol/messages.h>

namespace proto {

static const uint8_t kHeaderBytes = 4;
static const uint8_t kCrcBytes = 2;
static const uint16_t kMaxBody = kHeaderBytes + kMaxPayload + kCrcBytes;
static const uint16_t kMaxEncodedBody = kMaxBody + kMaxBody / 254u + 1u;
static const uint16_t kMaxWire = kMaxEncodedBody + 2u;  // with both delimiters

// Wire length of a frame with `payload_len` bytes, when its body holds no 0x00 run longer than
// 253 (always true while kMaxBody < 254): payload + header + crc + 1 COBS code + 2 delimiters.
inline uint16_t wire_size(uint8_t payload_len) {
    uint16_t body = static_cast<uint16_t>(kHeaderBytes + payload_len + kCrcBytes);
    return static_cast<uint16_t>(cobs_max_encoded(body) + 2u);
}

// Builds a complete wire frame into out. Returns its length, or 0 when payload_len exceeds
// kMaxPayload or out_cap < wire_size(payload_len).
uint16_t encode_frame(uint8_t type, uint16_t seq, const uint8_t* payload, uint8_t payload_len,
                      uint8_t* out, uint16_t out_cap);

// Encodes a generated message struct (see messages.h) as a frame.
template <class Msg>
uint16_t encode_message(const Msg& msg, uint16_t seq, uint8_t* out, uint16_t out_cap) {
    uint8_t payload[Msg::kSize > 0 ? Msg::kSize : 1];
    if (Msg::kSize == 0) payload[0] = 0;  // nothing to encode; keeps the byte defined
    msg.encode(payload);
    return encode_frame(Msg::kType, seq, payload, Msg::kSize, out, out_cap);
}

struct Frame {
    uint8_t version;
    uint8_t type;
    uint16_t seq;
    const uint8_t* payload;  // points into the decoder's buffer; valid until the next feed()
    uint8_t len;
};

// Streaming decoder: feed received bytes one at a time. A frame is returned only when its COBS
// is valid, its length is plausible and its CRC matches; anything else is counted and dropped.
// Resynchronises at the next 0x00.
class Decoder {
public:
    enum Status : uint8_t {
        kNone = 0,   // nothing complete yet
        kFrame,      // frame() holds a verified frame (version checked too)
        kError,      // a delimited block was rejected; error() says why
    };
    enum Error : uint8_t {
        kErrNone = 0,
        kErrCobs,      // invalid COBS (e.g. truncated by a lost byte)
        kErrTooShort,  // fewer bytes than header + CRC
        kErrTooLong,   // longer than the largest frame (overflow of the buffer)
        kErrCrc,       // CRC mismatch
        kErrVersion,   // intact frame of another protocol version
    };

    Decoder() { reset(); }
    void reset();
    Status feed(uint8_t byte);

    const Frame& frame() const { return frame_; }
    Error error() const { return error_; }
    // After kErrCrc or kErrVersion: the header as read (for the NAK's cmd_seq / cmd_type).
    bool error_has_header() const { return error_hdr_; }
    uint8_t error_type() const { return err_type_; }
    uint16_t error_seq() const { return err_seq_; }

    // Saturating counters since reset().
    uint16_t frames_ok() const { return frames_ok_; }
    uint16_t crc_errors() const { return crc_errors_; }
    uint16_t bad_frames() const { return bad_frames_; }  // COBS, length and version errors

private:
    Status finish();

    uint8_t buf_[kMaxEncodedBody];
    uint16_t n_;
    bool overflow_;
    Frame frame_;
    Error error_;
    bool error_hdr_;
    uint8_t err_type_;
    uint16_t err_seq_;
    uint16_t frames_ok_;
    uint16_t crc_errors_;
    uint16_t bad_frames_;
};

}  // namespace proto

#endif  // PROTOCOL_FRAME_H
