/* insncount: exact executed-instruction counts for marked regions (QEMU 7.2 TCG plugin, API v1).
 *
 * The firmware marks regions with hint instructions that execute as NOP:
 *   Arm (Thumb):  start `hint #10` = 0xBFA0, stop `hint #11` = 0xBFB0, report `hint #12` = 0xBFC0;
 *   RISC-V:       start `addi x0, x0, 10` = 0x00A00013, stop `… 11` = 0x00B00013, report `… 12` = 0x00C00013.
 * The set is chosen by QEMU's target name (an encoding of one is an ordinary instruction of the other).
 * Every executed instruction except the markers is counted (inline TCG add: exact even when a
 * translation block is left early). The instructions strictly between a start and the next stop are
 * added to the current sum; a report marker logs the sum (and the number of regions) and resets it.
 * Output (QEMU: `-d plugin -D <file>`):
 *   mark <n> <instructions> <regions>        at each report marker
 *   region <n> <instructions>                 each region, with the argument regions=on
 *   pc 0x<addr> <instructions>               with profile=on: per-PC counts inside regions, at exit;
 *                                            with profile_marks=A-B too: only the regions logged by report
 *                                            markers A to B − 1 (e.g. one scenario's frames)
 *   total <instructions>                      at exit (everything executed)
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "qemu-plugin-min.h"

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

/* The markers of the emulated architecture: their size in bytes and encodings. */
static size_t mark_size;
static uint32_t mark_start, mark_stop, mark_report;

static uint64_t count;    /* instructions executed, markers excluded */
static uint64_t start_at; /* count at the last start marker */
static uint64_t sum;      /* region instructions since the last report */
static unsigned regions;  /* regions since the last report */
static unsigned region_no, mark_no;
static int active, log_regions, profile;
static unsigned profile_from, profile_to = ~0u; /* report markers whose regions are profiled: [from, to) */

/* Per-PC counters for profile=on: open addressing on the PC. */
#define PROF_SLOTS (1u << 17)
struct prof { uint64_t pc; uint64_t n; };
static struct prof *prof;

static struct prof *prof_slot(uint64_t pc)
{
    uint32_t i = (uint32_t)((pc >> 1) * 2654435761u) & (PROF_SLOTS - 1);
    while (prof[i].pc != 0 && prof[i].pc != pc + 1) {
        i = (i + 1) & (PROF_SLOTS - 1);
    }
    prof[i].pc = pc + 1; /* + 1: 0 marks an empty slot */
    return &prof[i];
}

static void on_start(unsigned int vcpu, void *ud)
{
    (void)vcpu; (void)ud;
    if (active) {
        qemu_plugin_outs("warning: start marker inside a region, restarting it\n");
    }
    start_at = count;
    active = 1;
}

static void on_stop(unsigned int vcpu, void *ud)
{
    char buf[96];
    (void)vcpu; (void)ud;
    if (!active) {
        qemu_plugin_outs("warning: stop marker without start\n");
        return;
    }
    active = 0;
    sum += count - start_at;
    regions++;
    if (log_regions) {
        snprintf(buf, sizeof buf, "region %u %" PRIu64 "\n", region_no, count - start_at);
        qemu_plugin_outs(buf);
    }
    region_no++;
}

static void on_report(unsigned int vcpu, void *ud)
{
    char buf[96];
    (void)vcpu; (void)ud;
    snprintf(buf, sizeof buf, "mark %u %" PRIu64 " %u\n", mark_no++, sum, regions);
    qemu_plugin_outs(buf);
    sum = 0;
    regions = 0;
}

static void on_insn_profiled(unsigned int vcpu, void *ud)
{
    (void)vcpu;
    count++;
    if (active && mark_no >= profile_from && mark_no < profile_to) {
        ((struct prof *)ud)->n++;
    }
}

static void on_tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        if (qemu_plugin_insn_size(insn) == mark_size) {
            const uint8_t *d = qemu_plugin_insn_data(insn);
            uint32_t op = 0;
            for (size_t b = 0; b < mark_size; b++) {
                op |= (uint32_t)d[b] << (8 * b);
            }
            qemu_plugin_vcpu_udata_cb_t cb = op == mark_start ? on_start
                                           : op == mark_stop  ? on_stop
                                           : op == mark_report ? on_report : NULL;
            if (cb) {
                qemu_plugin_register_vcpu_insn_exec_cb(insn, cb, QEMU_PLUGIN_CB_NO_REGS, NULL);
                continue;
            }
        }
        if (profile) {
            struct prof *p = prof_slot(qemu_plugin_insn_vaddr(insn));
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_insn_profiled, QEMU_PLUGIN_CB_NO_REGS, p);
        } else {
            qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, &count, 1);
        }
    }
}

static void on_atexit(qemu_plugin_id_t id, void *ud)
{
    char buf[64];
    (void)id; (void)ud;
    if (profile) {
        for (uint32_t i = 0; i < PROF_SLOTS; i++) {
            if (prof[i].pc != 0 && prof[i].n != 0) {
                snprintf(buf, sizeof buf, "pc 0x%" PRIx64 " %" PRIu64 "\n", prof[i].pc - 1, prof[i].n);
                qemu_plugin_outs(buf);
            }
        }
    }
    snprintf(buf, sizeof buf, "total %" PRIu64 "\n", count);
    qemu_plugin_outs(buf);
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc,
                                           char **argv)
{
    for (int i = 0; i < argc; i++) {
        if (strcmp(argv[i], "regions=on") == 0) {
            log_regions = 1;
        } else if (strcmp(argv[i], "profile=on") == 0) {
            profile = 1;
        } else if (sscanf(argv[i], "profile_marks=%u-%u", &profile_from, &profile_to) == 2) {
            continue;
        } else {
            fprintf(stderr, "insncount: unknown argument %s (regions=on, profile=on, profile_marks=A-B)\n", argv[i]);
            return -1;
        }
    }
    if (strcmp(info->target_name, "arm") == 0) {
        mark_size = 2, mark_start = 0xBFA0u, mark_stop = 0xBFB0u, mark_report = 0xBFC0u;
    } else if (strncmp(info->target_name, "riscv", 5) == 0) {
        mark_size = 4, mark_start = 0x00A00013u, mark_stop = 0x00B00013u, mark_report = 0x00C00013u;
    } else {
        fprintf(stderr, "insncount: no markers known for target %s (arm, riscv32)\n", info->target_name);
        return -1;
    }
    if (info->system_emulation && info->system.smp_vcpus > 1) {
        qemu_plugin_outs("insncount: single vCPU only\n");
        return -1;
    }
    if (profile) {
        prof = calloc(PROF_SLOTS, sizeof *prof);
        if (!prof) {
            return -1;
        }
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb_trans);
    qemu_plugin_register_atexit_cb(id, on_atexit, NULL);
    return 0;
}
