; Interrupt-timing probe for the sim/common self-test (selftest.c): a bare ATmega2560 program
; whose phases (number in GPIOR0) put the core into the situations that the avrsim corrections
; are about. INT0/INT1/INT2 on rising edges; the harness drives PD0/PD1/PD2.
;   INT0 ISR: r21 <- r20 (main's counter), r23 <- r16 (main's phase register); 2 cycles
;   INT1 ISR: r22 <- r20; 1 cycle
;   INT2 ISR: re-enables interrupts first (as ISR_NOBLOCK does), r24 <- r20; its RETI finds
;             SREG.I set (label isr_int2_reti: the harness raises INT0 during that RETI)
#include <avr/io.h>

    .section .vectors, "ax", @progbits
    .global __vectors
__vectors:
    jmp main                    ; 0: reset
    jmp isr_int0                ; 1: INT0
    jmp isr_int1                ; 2: INT1
    jmp isr_int2                ; 3: INT2
    .rept 53
    jmp bad                     ; 4..56: unused
    .endr

    .text
isr_int0:
    mov r21, r20
    mov r23, r16
    reti
isr_int1:
    mov r22, r20
    reti
isr_int2:
    sei
    mov r24, r20
    .global isr_int2_reti
isr_int2_reti:
    reti
bad:
    rjmp bad

    .global main
main:
    ldi r16, hi8(RAMEND)
    out _SFR_IO_ADDR(SPH), r16
    ldi r16, lo8(RAMEND)
    out _SFR_IO_ADDR(SPL), r16
    ldi r16, (1 << ISC01) | (1 << ISC00) | (1 << ISC11) | (1 << ISC10) | (1 << ISC21) | (1 << ISC20)
    sts EICRA, r16
    ldi r16, (1 << INTF0) | (1 << INTF1) | (1 << INTF2)
    out _SFR_IO_ADDR(EIFR), r16 ; flags simavr latched while the pins sensed low level
    ldi r16, (1 << INT0) | (1 << INT1) | (1 << INT2)
    out _SFR_IO_ADDR(EIMSK), r16
    clr r20
    ; phase 1: awake; the harness makes INT0 and INT1 pending together
    ldi r16, 1
    out _SFR_IO_ADDR(GPIOR0), r16
    sei
    .rept 300
    inc r20
    .endr
    ; phase 2: idle sleep, woken by a stimulus between two steps
    ldi r16, (1 << SE)
    out _SFR_IO_ADDR(SMCR), r16
    ldi r16, 2
    out _SFR_IO_ADDR(GPIOR0), r16
    sleep
    ldi r16, 3
    ; phase 3: idle sleep, woken by a simavr cycle timer of the harness
    out _SFR_IO_ADDR(GPIOR0), r16
    sleep
    ; phase 4: INT0 made pending with interrupts off, then SEI
    cli
    ldi r16, 4
    out _SFR_IO_ADDR(GPIOR0), r16
1:  sbis _SFR_IO_ADDR(EIFR), INTF0
    rjmp 1b
    clr r20
    sei
    .rept 8
    inc r20
    .endr
    ; phase 5: SEI; SLEEP with INT0 already pending (the hardware sleeps and wakes at once)
    cli
    ldi r16, 5
    out _SFR_IO_ADDR(GPIOR0), r16
2:  sbis _SFR_IO_ADDR(EIFR), INTF0
    rjmp 2b
    sei
    sleep
    ; phase 6: awake; INT0 raised during the RETI of the INT2 ISR, which re-enabled interrupts
    ldi r16, 6
    out _SFR_IO_ADDR(GPIOR0), r16
    clr r20
    .rept 300
    inc r20
    .endr
    ldi r16, 7
    out _SFR_IO_ADDR(GPIOR0), r16
    cli
    sleep                       ; simavr: sleeping with interrupts off ends the simulation
