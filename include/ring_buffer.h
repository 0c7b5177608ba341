// Single-producer / single-consumer byte ring for ISR <-> main-loop queues (grbl style).
// N is a power of two <= 256; indices are uint8_t, so every index load/store is atomic on the
// AVR and no critical section is needed. One slot stays empty: capacity N - 1.
// Producer: push() only. Consumer: pop() only. Each side writes only its own index.
#ifndef FW_RING_BUFFER_H
#define FW_RING_BUFFER_H

#include <stdint.h>
#include <string.h>

template <uint16_t N>
class RingBuffer {
    static_assert(N >= 2 && N <= 256 && (N & (N - 1)) == 0, "N must be a power of two <= 256");
    static const uint8_t kMask = static_cast<uint8_t>(N - 1);

public:
    RingBuffer() : head_(0), tail_(0) {}

    static uint16_t capacity() { return N - 1; }

    // Producer side. False (nothing written) when full.
    bool push(uint8_t b) {
        uint8_t h = head_;
        uint8_t next = static_cast<uint8_t>((h + 1) & kMask);
        if (next == tail_) return false;
        buf_[h] = b;
        __asm__ __volatile__("" ::: "memory");  // the byte is stored before it is published
        head_ = next;
        return true;
    }
    // Producer side: n bytes as one unit (at most two memcpy, one publication). False (nothing
    // written) when they do not all fit.
    bool push_block(const uint8_t* p, uint16_t n) {
        if (n > free_slots()) return false;
        uint8_t h = head_;
        uint16_t first = static_cast<uint16_t>(N - h);
        if (first > n) first = n;
        memcpy(&buf_[h], p, first);
        memcpy(&buf_[0], p + first, n - first);
        __asm__ __volatile__("" ::: "memory");  // the bytes are stored before they are published
        head_ = static_cast<uint8_t>((h + n) & kMask);
        return true;
    }
    // Producer side: free slots (a lower bound while the consumer runs).
    uint16_t free_slots() const {
        return static_cast<uint16_t>((static_cast<uint8_t>(tail_ - head_ - 1)) & kMask);
    }

    // Consumer side. False when empty.
    bool pop(uint8_t* b) {
        uint8_t t = tail_;
        if (t == head_) return false;
        __asm__ __volatile__("" ::: "memory");  // read the byte after seeing it published
        *b = buf_[t];
        __asm__ __volatile__("" ::: "memory");
        tail_ = static_cast<uint8_t>((t + 1) & kMask);
        return true;
    }
    // Consumer side: bytes waiting (a lower bound while the producer runs).
    uint16_t used() const { return static_cast<uint8_t>(head_ - tail_) & kMask; }
    bool empty() const { return head_ == tail_; }

    // Only while neither side runs (init, tests).
    void clear() { head_ = tail_ = 0; }

private:
    volatile uint8_t head_;
    volatile uint8_t tail_;
    uint8_t buf_[N];
};

#endif  // FW_RING_BUFFER_H
