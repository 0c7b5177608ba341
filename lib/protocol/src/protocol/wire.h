// Little-endian field access and saturating float -> integer conversions used by the
// generated messages (<protocol/messages.h>). Hardware-free; AVR (gnu++11) and host.
#ifndef PROTOCOL_WIRE_H
#define PROTOCOL_WIRE_H

#include <stdint.h>
#include <string.h>

namespace proto {

inline void put_u8(uint8_t* p, uint8_t v) { p[0] = v; }
inline void put_u16(uint8_t* p, uint16_t v) {
    p[0] = static_cast<uint8_t>(v);
    p[1] = static_cast<uint8_t>(v >> 8);
}
inline void put_u32(uint8_t* p, uint32_t v) {
    p[0] = static_cast<uint8_t>(v);
    p[1] = static_cast<uint8_t>(v >> 8);
    p[2] = static_cast<uint8_t>(v >> 16);
    p[3] = static_cast<uint8_t>(v >> 24);
}
inline void put_i8(uint8_t* p, int8_t v) { put_u8(p, static_cast<uint8_t>(v)); }
inline void put_i16(uint8_t* p, int16_t v) { put_u16(p, static_cast<uint16_t>(v)); }
inline void put_i32(uint8_t* p, int32_t v) { put_u32(p, static_cast<uint32_t>(v)); }
inline void put_f32(uint8_t* p, float v) {
    // IEEE 754 binary32 on both AVR and host; byte order made explicit via the u32 image.
    uint32_t u;
    memcpy(&u, &v, sizeof u);
    put_u32(p, u);
}

inline uint8_t get_u8(const uint8_t* p) { return p[0]; }
inline uint16_t get_u16(const uint8_t* p) {
    return static_cast<uint16_t>(p[0] | (static_cast<uint16_t>(p[1]) << 8));
}
inline uint32_t get_u32(const uint8_t* p) {
    return static_cast<uint32_t>(p[0]) | (static_cast<uint32_t>(p[1]) << 8) |
           (static_cast<uint32_t>(p[2]) << 16) | (static_cast<uint32_t>(p[3]) << 24);
}
inline int8_t get_i8(const uint8_t* p) { return static_cast<int8_t>(p[0]); }
inline int16_t get_i16(const uint8_t* p) { return static_cast<int16_t>(get_u16(p)); }
inline int32_t get_i32(const uint8_t* p) { return static_cast<int32_t>(get_u32(p)); }
inline float get_f32(const uint8_t* p) {
    uint32_t u = get_u32(p);
    float v;
    memcpy(&v, &u, sizeof v);
    return v;
}

// Saturating conversion of a physical value to a raw integer: raw = round(value * inv_scale).
// Returns false when the value was NaN (raw set to 0) or outside the raw range (raw clamped).
inline bool sat_to_raw(float value, float inv_scale, float lo, float hi, float* raw_out) {
    float x = value * inv_scale;
    if (x != x) {  // NaN
        *raw_out = 0.0f;
        return false;
    }
    if (x >= hi) {
        *raw_out = hi;
        return x == hi;
    }
    if (x <= lo) {
        *raw_out = lo;
        return x == lo;
    }
    *raw_out = x >= 0.0f ? x + 0.5f : x - 0.5f;  // truncation below rounds half away from zero
    return true;
}
inline bool sat_i16(float value, float inv_scale, int16_t* out) {
    float r;
    bool ok = sat_to_raw(value, inv_scale, -32768.0f, 32767.0f, &r);
    *out = static_cast<int16_t>(r);
    return ok;
}
inline bool sat_u16(float value, float inv_scale, uint16_t* out) {
    float r;
    bool ok = sat_to_raw(value, inv_scale, 0.0f, 65535.0f, &r);
    *out = static_cast<uint16_t>(r);
    return ok;
}
inline bool sat_u8(float value, float inv_scale, uint8_t* out) {
    float r;
    bool ok = sat_to_raw(value, inv_scale, 0.0f, 255.0f, &r);
    *out = static_cast<uint8_t>(r);
    return ok;
}
inline bool sat_i32(float value, float inv_scale, int32_t* out) {
    // 2^31 is exactly representable as float; every float below it is <= 2147483520.
    float r;
    bool ok = sat_to_raw(value, inv_scale, -2147483648.0f, 2147483648.0f, &r);
    if (r >= 2147483648.0f) {
        *out = static_cast<int32_t>(0x7FFFFFFFL);
        return false;
    }
    *out = static_cast<int32_t>(r);
    return ok;
}
inline bool sat_u32(float value, float inv_scale, uint32_t* out) {
    float r;
    bool ok = sat_to_raw(value, inv_scale, 0.0f, 4294967296.0f, &r);
    if (r >= 4294967296.0f) {
        *out = 0xFFFFFFFFul;
        return false;
    }
    *out = static_cast<uint32_t>(r);
    return ok;
}
// Integer down-scaling (e.g. cycles -> units of 16 cycles), saturating at the u16 maximum.
inline uint16_t sat_div_u16(uint32_t value, uint32_t divisor) {
    uint32_t q = value / divisor;
    return q > 65535u ? static_cast<uint16_t>(65535u) : static_cast<uint16_t>(q);
}
// Saturating increment for error counters.
inline void sat_inc(uint16_t* c) {
    if (*c != 0xFFFFu) ++*c;
}

}  // namespace proto

#endif  // PROTOCOL_WIRE_H
