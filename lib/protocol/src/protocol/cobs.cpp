#include <protocol/cobs.h>

namespace proto {

uint16_t cobs_encode(const uint8_t* in, uint16_t len, uint8_t* out, uint16_t out_cap) {
    if (out_cap < cobs_max_encoded(len)) return 0;
    uint16_t code_pos = 0;
    uint16_t o = 1;
    uint8_t code = 1;
    for (uint16_t i = 0; i < len; ++i) {
        if (in[i] == 0) {
            out[code_pos] = code;
            code_pos = o++;
            code = 1;
        } else {
            out[o++] = in[i];
            if (++code == 0xFF) {
                out[code_pos] = code;
                code_pos = o++;
                code = 1;
            }
        }
    }
    out[code_pos] = code;
    return o;
}

int16_t cobs_decode(const uint8_t* in, uint16_t len, uint8_t* out, uint16_t out_cap) {
    uint16_t i = 0;
    uint16_t o = 0;
    while (i < len) {
        uint8_t code = in[i];
        if (code == 0) return -1;
        uint16_t end = static_cast<uint16_t>(i + code);
        if (end > len) return -1;  // block runs past the end: truncated frame
        ++i;
        while (i < end) {
            if (in[i] == 0 || o >= out_cap) return -1;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < len) {
            if (o >= out_cap) return -1;
            out[o++] = 0;
        }
    }
    return static_cast<int16_t>(o);
}

}  // namespace proto
