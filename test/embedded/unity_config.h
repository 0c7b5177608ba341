// Unity configuration for the embedded suites (simulated ATmega2560 and the board): Unity's
// output goes to USART0 (pins 0/1, the USB bridge; simavr prints it on the console).
// Build with -DUNITY_INCLUDE_CONFIG_H -Itest/embedded, and unity.c with -UAVR (Unity 2.5 puts
// its strings in PROGMEM under #ifdef AVR but reads them as RAM).
// Header-only, so every suite (and test/embedded/test_protocol*) can use it without a shared
// source file.
#ifndef TEST_EMBEDDED_UNITY_CONFIG_H
#define TEST_EMBEDDED_UNITY_CONFIG_H

#ifdef __AVR__
#include <avr/io.h>
#include <util/delay_basic.h>

#ifndef UNITY_UART0_UBRR
#define UNITY_UART0_UBRR 16  // 115200 baud with U2X at 16 MHz
#endif

static inline void unity_uart0_init(void) {
    UBRR0 = UNITY_UART0_UBRR;
    UCSR0A = (1 << U2X0);
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);
    UCSR0B = (1 << TXEN0);
}
static unsigned char unity_uart0_sent;  // a byte was written since the last flush

// The UART is polled at most every 765 cycles (_delay_loop_1(255): 3 cycles a count), about
// twice per byte (1,360 cycles at 117,647 baud). Under simavr 1.6 every read of UCSR0A while
// nothing has been received and TXC0 is clear costs the host a usleep() (avr_uart.c,
// AVR_UART_FLAG_POLL_SLEEP, set by the stock simavr program that `pio test -e simavr` runs):
// a tight loop made each printed line take seconds of wall time. On the board the pause
// delays a byte by at most 48 us.
#define UNITY_UART0_POLL_PAUSE() _delay_loop_1(255)

static inline void unity_uart0_putc(char c) {
    while (!(UCSR0A & (1 << UDRE0))) {
        UNITY_UART0_POLL_PAUSE();
    }
    UCSR0A = (1 << U2X0) | (1 << TXC0);  // clear TXC0 (write one): set again when this byte is out
    UDR0 = (unsigned char)c;
    unity_uart0_sent = 1;
}
// Waits until the last byte has left the shift register, so that nothing is cut off when the
// test program stops the CPU right after UNITY_END().
static inline void unity_uart0_flush(void) {
    if (!unity_uart0_sent) return;
    while (!(UCSR0A & (1 << TXC0))) {
        UNITY_UART0_POLL_PAUSE();
    }
    unity_uart0_sent = 0;
}

#define UNITY_OUTPUT_START() unity_uart0_init()
#define UNITY_OUTPUT_CHAR(c) unity_uart0_putc((char)(c))
#define UNITY_OUTPUT_FLUSH() unity_uart0_flush()
#define UNITY_OUTPUT_COMPLETE() unity_uart0_flush()
#endif  // __AVR__

#ifdef __AVR__
#define UNITY_EXCLUDE_DOUBLE  // double is float on avr-gcc 5.4
#endif

#endif  // TEST_EMBEDDED_UNITY_CONFIG_H
