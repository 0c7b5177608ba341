/*
 * ATmega2560 register, bit and vector names for host programs that read a simulated core's
 * data space: avr-libc's own <avr/iom2560.h> (the header the firmware compiles against), with
 * its access macros turned into plain data-space addresses. PORTH is then 0x102, PIND 0x29
 * (I/O address + 0x20), OCR3C 0x9C (low byte; read 16-bit registers with avrsim_rd16), PH6 the
 * bit number 6, INT0_vect the vector number 1.
 *
 * Include it after every other header (its macros are short upper-case names such as SE or
 * ADC). The include path is avr-libc's, searched after the host's own (host_tools/_build.py:
 * -idirafter), so that only <avr/...> resolves there.
 */
#ifndef SIM_COMMON_AVR_REGS_H
#define SIM_COMMON_AVR_REGS_H

#define _AVR_IO_H_ 1 /* the device header insists on being included through <avr/io.h> */
#define _SFR_IO8(io_addr) ((io_addr) + 0x20)
#define _SFR_IO16(io_addr) ((io_addr) + 0x20)
#define _SFR_MEM8(mem_addr) (mem_addr)
#define _SFR_MEM16(mem_addr) (mem_addr)
#define _VECTOR(n) (n)
#include <avr/iom2560.h>

#endif /* SIM_COMMON_AVR_REGS_H */
