/* simavr harness for bench/plant/avr_cycles.sh: runs an ATmega2560 ELF and prints the CPU
 * cycle count at every write to GPIOR0 (data address 0x3E), and the differences. */
#include <stdio.h>
#include <stdlib.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_io.h>

static uint64_t g_last;
static int g_have_last;

static void on_marker(struct avr_t* avr, avr_io_addr_t addr, uint8_t v, void* param) {
  (void)addr;
  (void)param;
  if (g_have_last)
    printf("marker %u: cycle %llu (+%llu since the previous marker)\n", v,
           (unsigned long long)avr->cycle, (unsigned long long)(avr->cycle - g_last));
  else
    printf("marker %u: cycle %llu\n", v, (unsigned long long)avr->cycle);
  g_last = avr->cycle;
  g_have_last = 1;
}

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: %s firmware.elf\n", argv[0]);
    return 2;
  }
  elf_firmware_t fw = {{0}};
  if (elf_read_firmware(argv[1], &fw) != 0) {
    fprintf(stderr, "cannot read %s\n", argv[1]);
    return 2;
  }
  avr_t* avr = avr_make_mcu_by_name("atmega2560");
  if (!avr) return 2;
  avr_init(avr);
  avr->frequency = 16000000;
  avr_load_firmware(avr, &fw);
  avr_register_io_write(avr, 0x3E, on_marker, NULL);
  int state = cpu_Running;
  for (long i = 0; i < 10000000 && state != cpu_Done && state != cpu_Crashed; ++i) state = avr_run(avr);
  return state == cpu_Done ? 0 : 1;
}
