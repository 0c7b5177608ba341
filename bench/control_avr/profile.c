/* Cycle profile of the control benchmark (libsimavr): runs an ATmega2560 ELF to its end and
 * prints, for every program address that executed, the CPU cycles spent there ("pc cycles",
 * pc as a byte address in hex). bench/control_avr/profile.sh maps the addresses to source
 * lines, and the cycles spent in each CTL_PROBE region ("region n cycles"). simavr charges each instruction its datasheet cycle count; no interrupts are used by
 * the benchmark, so no response-time correction is needed.
 * Usage: profile bench.elf > pcs.txt */
#include <stdio.h>
#include <stdlib.h>

#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: %s firmware.elf\n", argv[0]); return 2; }
    elf_firmware_t fw = {{0}};
    if (elf_read_firmware(argv[1], &fw)) { fprintf(stderr, "cannot read %s\n", argv[1]); return 2; }
    avr_t *avr = avr_make_mcu_by_name("atmega2560");
    if (!avr) return 2;
    avr_init(avr);
    avr->frequency = 16000000;
    avr_load_firmware(avr, &fw);
    const size_t n = 256u * 1024u;
    unsigned long long *cyc = calloc(n, sizeof *cyc);
    unsigned long long region[256] = {0};
    if (!cyc) return 2;
    for (;;) {
        const avr_flashaddr_t pc = avr->pc;
        const avr_cycle_count_t c0 = avr->cycle;
        const int st = avr_run(avr);
        if (pc < n) cyc[pc] += avr->cycle - c0;
        region[avr->data[0x3e]] += avr->cycle - c0;  /* GPIOR0: CTL_PROBE region marker */
        if (st == cpu_Done || st == cpu_Crashed || avr->state == cpu_Sleeping) break;
    }
    for (int r = 1; r < 256; ++r)
        if (region[r]) printf("region %d %llu\n", r, region[r]);
    for (size_t pc = 0; pc < n; ++pc)
        if (cyc[pc]) printf("%zx %llu\n", pc, cyc[pc]);
    return 0;
}
