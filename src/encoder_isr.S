; Quadrature encoder ISRs for INT0..INT3 (PD0..PD3; names in include/board.h), hand-written
; for cycle count.
; Design and cycle budget: docs/firmware.md, "Encoder ISR". Summary (ATmega2560 cycles):
;   5 (interrupt response) + 3 (vector JMP) + 19 (prologue, table lookup, IJMP)
;   + 6 (count handler) + 6 (epilogue) + 5 (RETI) = 44 cycles per edge.
;
; State kept in I/O registers (1-cycle IN/OUT, never touched by other code):
;   ENC_PREV_L_GPIOR (GPIOR0) = left  wheel previous pin state (ENC_PIN & ENC_LEFT_MASK)
;   ENC_PREV_R_GPIOR (GPIOR1) = right wheel previous pin state (ENC_PIN & ENC_RIGHT_MASK)
;   ENC_SREG_GPIOR   (GPIOR2) = SREG stash (encoder ISRs never nest: I is cleared on entry and never set)
; Counters in SRAM (written only here; read by enc_snapshot() with interrupts off):
;   enc_raw_l/r  uint16  position, wraps mod 2^16, extended to int32 by enc_snapshot()
;   enc_ill_l/r  uint16  illegal transitions (both channels changed), wraps, extended likewise
;
; Dispatch: index = (prev << 4) | cur. Left states sit in bits 0-1, so the index uses bits
; {0,1,4,5}; right states sit in bits 2-3, index bits {2,3,6,7}. The two index sets only share
; 0x00 (no change for both), so one 256-byte table serves both wheels. Each entry is the low
; byte of the word address of a handler; all handlers lie in the first 512 bytes of this
; 512-aligned section, so the high byte is constant.

#include <avr/io.h>
#include "board.h"

#define PREV_L     _SFR_IO_ADDR(ENC_PREV_L_GPIOR)
#define PREV_R     _SFR_IO_ADDR(ENC_PREV_R_GPIOR)
#define SREG_STASH _SFR_IO_ADDR(ENC_SREG_GPIOR)
#define SREG_IO    _SFR_IO_ADDR(SREG)
#define PINS_IO    _SFR_IO_ADDR(ENC_PIN)

; The dispatch below needs the left pair in bits 0-1 and the right pair in bits 2-3.
#if ENC_LEFT_MASK != 0x03 || ENC_RIGHT_MASK != 0x0C
#error "encoder_isr.S: the transition table needs the left encoder on bits 0-1 and the right on bits 2-3 of ENC_PIN"
#endif

    .section .bss.enc_counters,"aw",@nobits
    .global enc_raw_l
    .global enc_raw_r
    .global enc_ill_l
    .global enc_ill_r
enc_raw_l:  .skip 2
enc_raw_r:  .skip 2
enc_ill_l:  .skip 2
enc_ill_r:  .skip 2

    .section .text.enc_isr,"ax",@progbits
    .balign 512
enc_base:

; ---- vectors: INT0/INT1 = left wheel, INT2/INT3 = right wheel ----------------------------
    .global ENC_LEFT_A_VECT
    .global ENC_LEFT_B_VECT
ENC_LEFT_A_VECT:                    ; INT0, PD0, left A
ENC_LEFT_B_VECT:                    ; INT1, PD1, left B
    push  r30                       ; 2
    in    r30, SREG_IO              ; 1
    out   SREG_STASH, r30           ; 1
    push  r31                       ; 2
    in    r30, PINS_IO              ; 1   sample the pins
    andi  r30, ENC_LEFT_MASK        ; 1   cur (left)
    in    r31, PREV_L               ; 1   prev
    out   PREV_L, r30               ; 1   prev := cur
    swap  r31                       ; 1   prev << 4
    or    r30, r31                  ; 1   index
    ldi   r31, hi8(enc_table)       ; 1
    lpm   r30, Z                    ; 3   handler word address, low byte
    ldi   r31, pm_hi8(enc_base)     ; 1
    ijmp                            ; 2   = 19

    .global ENC_RIGHT_A_VECT
    .global ENC_RIGHT_B_VECT
ENC_RIGHT_A_VECT:                   ; INT2, PD2, right A
ENC_RIGHT_B_VECT:                   ; INT3, PD3, right B
    push  r30
    in    r30, SREG_IO
    out   SREG_STASH, r30
    push  r31
    in    r30, PINS_IO
    andi  r30, ENC_RIGHT_MASK       ; cur (right)
    in    r31, PREV_R
    out   PREV_R, r30
    swap  r31
    or    r30, r31
    ldi   r31, hi8(enc_table)
    lpm   r30, Z
    ldi   r31, pm_hi8(enc_base)
    ijmp

; ---- handlers: 6 cycles on the common path, then the epilogue ----------------------------
.macro EPILOGUE
    pop   r31                       ; 2
    in    r30, SREG_STASH           ; 1
    out   SREG_IO, r30              ; 1
    pop   r30                       ; 2
    reti                            ; 5
.endm

; 16-bit increment of \var: the high byte is only touched when the low byte wraps.
.macro INC16 var
    lds   r31, \var                 ; 2
    subi  r31, 0xFF                 ; 1   +1, Z set on wrap to 0
    sts   \var, r31                 ; 2
    breq  1f                        ; 1
    EPILOGUE
1:  lds   r31, \var+1
    subi  r31, 0xFF
    sts   \var+1, r31
    EPILOGUE
.endm

.macro DEC16 var
    lds   r31, \var                 ; 2
    subi  r31, 0x01                 ; 1   -1, C set on borrow (was 0)
    sts   \var, r31                 ; 2
    brcs  1f                        ; 1
    EPILOGUE
1:  lds   r31, \var+1
    subi  r31, 0x01
    sts   \var+1, r31
    EPILOGUE
.endm

h_none:
    EPILOGUE
h_inc_l:
    INC16 enc_raw_l
h_dec_l:
    DEC16 enc_raw_l
h_ill_l:
    INC16 enc_ill_l
h_inc_r:
    INC16 enc_raw_r
h_dec_r:
    DEC16 enc_raw_r
h_ill_r:
    INC16 enc_ill_r
enc_handlers_end:

.if (enc_handlers_end - enc_base) > 512
.error "encoder handlers must lie in the first 512 bytes of the section (constant pm_hi8)"
.endif

; ---- the transition table ----------------------------------------------------------------
; step = (pos(cur) - pos(prev)) mod 4 with pos(s) = s ^ (s >> 1) (Gray position, A = bit 0):
; 0 none, 1 forward when A leads B, 3 backward, 2 illegal (both channels changed).
.macro ENTRY_FOR p, c, inc, dec, ill
    .set pp, (\p) ^ ((\p) >> 1)
    .set cp, (\c) ^ ((\c) >> 1)
    .set st, (cp - pp) & 3
    .if st == 0
        .byte (h_none - enc_base) / 2
    .elseif st == 1
        .byte (\inc - enc_base) / 2
    .elseif st == 3
        .byte (\dec - enc_base) / 2
    .else
        .byte (\ill - enc_base) / 2
    .endif
.endm

    .balign 256
    .global enc_table
enc_table:
    .set idx, 0
    .rept 256
    .if (idx & 0xCC) == 0
        ; left (also index 0: no change)
        .if ENC_LEFT_REVERSED
            ENTRY_FOR ((idx >> 4) & 3), (idx & 3), h_dec_l, h_inc_l, h_ill_l
        .else
            ENTRY_FOR ((idx >> 4) & 3), (idx & 3), h_inc_l, h_dec_l, h_ill_l
        .endif
    .elseif (idx & 0x33) == 0
        .if ENC_RIGHT_REVERSED
            ENTRY_FOR ((idx >> 6) & 3), ((idx >> 2) & 3), h_dec_r, h_inc_r, h_ill_r
        .else
            ENTRY_FOR ((idx >> 6) & 3), ((idx >> 2) & 3), h_inc_r, h_dec_r, h_ill_r
        .endif
    .else
        .byte (h_none - enc_base) / 2   ; unreachable index
    .endif
    .set idx, idx + 1
    .endr
