/*
 * A QEMU TCG plugin (plugin API version 1, QEMU 7.2) for the TLS spike's
 * M4 images: counts the guest instructions executed between each execution
 * of the function at `enter` and the next of the one at `leave`, adds them
 * up, and at each execution of `phase` prints the sum so far and starts a
 * new one. The spike programs call mark_server_enter / mark_server_leave
 * around every call into the server and mark_phase after each handshake.
 *
 *   gcc -O2 -shared -fPIC -o marks.so marks.c
 *   qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native \
 *       -icount shift=0 -kernel IMAGE \
 *       -plugin ./marks.so,enter=0x...,leave=0x...,phase=0x...
 *   (addresses: llvm-nm IMAGE | grep mark_)
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef uint64_t qemu_plugin_id_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
typedef struct qemu_info_t qemu_info_t;
enum qemu_plugin_op { QEMU_PLUGIN_INLINE_ADD_U64 = 0 };
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS = 0 };

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t, void (*)(qemu_plugin_id_t, struct qemu_plugin_tb *));
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *, size_t);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *);
void qemu_plugin_register_vcpu_insn_exec_inline(struct qemu_plugin_insn *, enum qemu_plugin_op, void *, uint64_t);
void qemu_plugin_register_vcpu_insn_exec_cb(struct qemu_plugin_insn *, void (*)(unsigned int, void *),
                                            enum qemu_plugin_cb_flags, void *);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t, void (*)(qemu_plugin_id_t, void *), void *);
void qemu_plugin_outs(const char *);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

static uint64_t total, start, sum, windows, enter_addr, leave_addr, phase_addr;
static int inside, phase_no;

static void on_enter(unsigned int vcpu, void *u) { (void)vcpu; (void)u; start = total; inside = 1; }
static void on_leave(unsigned int vcpu, void *u) {
    (void)vcpu; (void)u;
    if (inside) { sum += total - start; windows++; inside = 0; }
}
static void on_phase(unsigned int vcpu, void *u) {
    char line[160];
    (void)vcpu; (void)u;
    snprintf(line, sizeof line, "marks: phase %d: %" PRIu64 " server instructions in %" PRIu64
             " windows (%" PRIu64 " instructions in all so far)\n", ++phase_no, sum, windows, total);
    qemu_plugin_outs(line);
    sum = 0; windows = 0;
}

static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t va = qemu_plugin_insn_vaddr(insn);
        qemu_plugin_register_vcpu_insn_exec_inline(insn, QEMU_PLUGIN_INLINE_ADD_U64, &total, 1);
        if (va == enter_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, on_enter, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == leave_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, on_leave, QEMU_PLUGIN_CB_NO_REGS, NULL);
        if (va == phase_addr) qemu_plugin_register_vcpu_insn_exec_cb(insn, on_phase, QEMU_PLUGIN_CB_NO_REGS, NULL);
    }
}

static void at_exit(qemu_plugin_id_t id, void *p) {
    char line[120];
    (void)id; (void)p;
    snprintf(line, sizeof line, "marks: %" PRIu64 " instructions in all\n", total);
    qemu_plugin_outs(line);
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                                               int argc, char **argv) {
    (void)info;
    for (int i = 0; i < argc; i++) {
        char *eq = strchr(argv[i], '=');
        if (!eq) return -1;
        uint64_t v = strtoull(eq + 1, NULL, 0) & ~1ULL; /* Thumb: bit 0 of a symbol is not in the address */
        if (!strncmp(argv[i], "enter=", 6)) enter_addr = v;
        else if (!strncmp(argv[i], "leave=", 6)) leave_addr = v;
        else if (!strncmp(argv[i], "phase=", 6)) phase_addr = v;
        else return -1;
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    qemu_plugin_register_atexit_cb(id, at_exit, NULL);
    return 0;
}
