// Consistent Overhead Byte Stuffing (Cheshire & Baker): removes every 0x00 from a block so
// that 0x00 can delimit frames. Encoded length <= len + len/254 + 1.
#ifndef PROTOCOL_COBS_H
#define PROTOCOL_COBS_H

#include <stdint.h>

namespace proto {

inline uint16_t cobs_max_encoded(uint16_t len) { return static_cast<uint16_t>(len + len / 254u + 1u); }

// Encodes in[0..len) into out (no delimiters). Returns the encoded length, or 0 when out_cap
// is too small (out then holds garbage). in and out must not overlap.
uint16_t cobs_encode(const uint8_t* in, uint16_t len, uint8_t* out, uint16_t out_cap);

// Decodes an encoded block (without delimiters) into out. Returns the decoded length, or -1
// when the block is not valid COBS (contains 0x00, a code runs past the end) or out_cap is too
// small. out may equal in (in-place decoding).
int16_t cobs_decode(const uint8_t* in, uint16_t len, uint8_t* out, uint16_t out_cap);

}  // namespace proto

#endif  // PROTOCOL_COBS_H
