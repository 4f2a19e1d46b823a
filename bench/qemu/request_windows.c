/*
 * A QEMU TCG plugin that counts the guest instructions of each request the
 * mps2-an386 image serves: from the LAN9118's interrupt (a frame came in)
 * to the core going idle again, with the instruction at which the reply
 * frame was handed to the chip. Loaded by scripts/bench-mcu; it needs no
 * change to the image, so what it measures is the image that ships.
 * Loaded by scripts/bench-tls too, for TLS handshakes, which span several
 * windows.
 *
 *   qemu-system-arm ... -plugin request_windows.so,irq=0x458,tick=0x4e8,ctl=CTL,out=OUT[,live=1]
 *
 *   irq   the address of the handler the LAN9118's interrupt runs (its
 *         vector): executing it opens a window (it also counts later entries)
 *   tick  the SysTick handler's address: entries inside a window are counted
 *   ctl   a file holding the current phase, a small number written by the
 *         client before each series of requests (0: not measured); read at
 *         each window's start
 *   out   where the windows and the traces are written
 *   live  1: also write a line when a window opens, and flush every line,
 *         so that a client reading `out` as the guest runs knows whether
 *         the core is busy (scripts/bench-tls waits for it to go idle)
 *
 * A window closes when the vCPU goes idle (`wfi` with nothing pending).
 * Inside it the plugin notes, in instructions from the window's start, the
 * LAN9118 accesses that mark the path of a frame (datasheet register map,
 * offsets from 0x4020_0000), and the last interrupt entry after the first:
 *
 *   irq_last    the last entry to the interrupt's handler after the one that
 *               opened the window
 *   rx_status   the first read of RX_STATUS_FIFO (0x40): the driver takes a frame
 *   rx_data     the last read of the RX data FIFO (0x00-0x1c): the frame is copied out
 *   tx_first    the first write to the TX data FIFO (0x20-0x3c): a frame goes out
 *   tx_last     the last such write: the reply's last word is in the chip
 *
 * Output, one line per window:
 *
 *   W phase instructions irqs ticks rx_frames tx_frames irq_last rx_status rx_data tx_first tx_last
 *     outside outside_ticks
 *
 * (-1 for a mark that did not happen; outside: the instructions executed
 * between the previous window's close and this one's opening, none of them
 * in a window: SysTick and the work of timers while no frame came, and the
 * executor's loop after a wake-up; outside_ticks: SysTick's entries among
 * them), with live=1 a line when a window opens
 *
 *   O phase
 *
 * and for the first TRACES request
 * windows (one frame in, one frame out) of each phase, every executed
 * address in order (hexadecimal), for where-the-instructions-go questions:
 *
 *   T phase instructions tx_last address address ...
 *
 * Counts are of executed guest instructions (one callback per instruction),
 * so they repeat exactly for the same path; they do not depend on the host.
 *
 * The QEMU plugin API (version 1, QEMU 7.x) is declared below, only the
 * calls this file makes: Debian ships QEMU with plugin support but not its
 * header. Built by scripts/bench-mcu: gcc -O2 -shared -fPIC.
 */
#include <fcntl.h>
#include <inttypes.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* --- the QEMU plugin API, version 1 ------------------------------------ */

typedef uint64_t qemu_plugin_id_t;
typedef uint32_t qemu_plugin_meminfo_t;
struct qemu_plugin_tb;
struct qemu_plugin_insn;
typedef struct qemu_info_t qemu_info_t;

enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS };
enum qemu_plugin_mem_rw { QEMU_PLUGIN_MEM_R = 1, QEMU_PLUGIN_MEM_W, QEMU_PLUGIN_MEM_RW };

typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
typedef void (*qemu_plugin_vcpu_udata_cb_t)(unsigned int vcpu_index, void *userdata);
typedef void (*qemu_plugin_vcpu_simple_cb_t)(qemu_plugin_id_t id, unsigned int vcpu_index);
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);
typedef void (*qemu_plugin_vcpu_mem_cb_t)(unsigned int vcpu_index, qemu_plugin_meminfo_t info,
                                          uint64_t vaddr, void *userdata);

void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
void qemu_plugin_register_vcpu_idle_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_simple_cb_t cb);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);
void qemu_plugin_register_vcpu_insn_exec_cb(struct qemu_plugin_insn *insn, qemu_plugin_vcpu_udata_cb_t cb,
                                            enum qemu_plugin_cb_flags flags, void *userdata);
void qemu_plugin_register_vcpu_mem_cb(struct qemu_plugin_insn *insn, qemu_plugin_vcpu_mem_cb_t cb,
                                      enum qemu_plugin_cb_flags flags, enum qemu_plugin_mem_rw rw,
                                      void *userdata);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *tb, size_t idx);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *insn);
bool qemu_plugin_mem_is_store(qemu_plugin_meminfo_t info);
void qemu_plugin_outs(const char *string);

__attribute__((visibility("default"))) int qemu_plugin_version = 1;

/* --- the board ------------------------------------------------------------ */

/* The LAN9118's register window and the offsets that mark a frame's path. */
#define LAN9118_BASE 0x40200000u
#define LAN9118_WINDOW 0x100u
#define RX_DATA_FIFO_END 0x20u  /* 0x00-0x1c: RX data FIFO port (aliases) */
#define TX_DATA_FIFO_END 0x40u  /* 0x20-0x3c: TX data FIFO port (aliases) */
#define RX_STATUS_FIFO 0x40u
/* Phases the client may name (ctl), instructions one window may trace, and
 * request windows traced per phase. */
#define MAX_PHASES 16
#define TRACE_MAX (1u << 20)
#define TRACES 16
#define NONE UINT64_MAX

enum lan_access { ACCESS_OTHER, ACCESS_TX_DATA };

struct window {
    bool open;
    int phase;
    uint64_t instructions;
    unsigned irqs, ticks, rx_frames, tx_frames;
    uint64_t irq_last, rx_status, rx_data, tx_first, tx_last;
    enum lan_access last_access;
};

static uint64_t irq_pc = NONE, tick_pc = NONE;
static int ctl_fd = -1;
static FILE *out;
static bool live;
static struct window w;
/* Executed while no window was open, since the last window closed. */
static uint64_t outside, outside_ticks;
/* The addresses executed in the open window, in order. */
static uint32_t *trace;
/* Per phase: request windows traced so far. */
static unsigned traced[MAX_PHASES];

static int read_phase(void)
{
    char text[16] = {0};
    if (ctl_fd < 0 || pread(ctl_fd, text, sizeof text - 1, 0) <= 0) {
        return 0;
    }
    int phase = atoi(text);
    return phase > 0 && phase < MAX_PHASES ? phase : 0;
}

static void open_window(void)
{
    memset(&w, 0, sizeof w);
    w.open = true;
    w.phase = read_phase();
    w.irq_last = w.rx_status = w.rx_data = w.tx_first = w.tx_last = NONE;
    if (live) {
        fprintf(out, "O %d\n", w.phase);
        fflush(out);
    }
}

static long long mark(uint64_t at)
{
    return at == NONE ? -1 : (long long)at;
}

/* The rule scripts/bench-mcu uses too: one frame in, one frame out. */
static bool is_request(const struct window *v)
{
    return v->phase > 0 && v->rx_frames == 1 && v->tx_frames == 1;
}

static void write_trace(void)
{
    fprintf(out, "T %d %" PRIu64 " %" PRIu64, w.phase, w.instructions, w.tx_last);
    for (uint64_t i = 0; i < w.instructions; i++) {
        fprintf(out, " %" PRIx32, trace[i]);
    }
    fputc('\n', out);
}

static void close_window(void)
{
    w.open = false;
    fprintf(out, "W %d %" PRIu64 " %u %u %u %u %lld %lld %lld %lld %lld %" PRIu64 " %" PRIu64 "\n", w.phase,
            w.instructions, w.irqs, w.ticks, w.rx_frames, w.tx_frames, mark(w.irq_last), mark(w.rx_status),
            mark(w.rx_data), mark(w.tx_first), mark(w.tx_last), outside, outside_ticks);
    outside = outside_ticks = 0;
    if (is_request(&w) && w.instructions <= TRACE_MAX && traced[w.phase] < TRACES) {
        traced[w.phase]++;
        write_trace();
    }
    if (live) {
        fflush(out);
    }
}

/* --- callbacks ------------------------------------------------------------ */

static void on_irq(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    (void)udata;
    if (!w.open) {
        open_window();
    } else {
        w.irq_last = w.instructions;
    }
    w.irqs++;
}

static void on_tick(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    (void)udata;
    if (w.open) {
        w.ticks++;
    } else {
        outside_ticks++;
    }
}

static void on_insn(unsigned int vcpu, void *udata)
{
    (void)vcpu;
    if (!w.open) {
        outside++;
        return;
    }
    if (w.instructions < TRACE_MAX) {
        trace[w.instructions] = (uint32_t)(uintptr_t)udata;
    }
    w.instructions++;
}

/* Runs after the access, whose instruction on_insn has counted: marks are
 * "instructions executed up to and including this one", minus one. */
static void on_mem(unsigned int vcpu, qemu_plugin_meminfo_t info, uint64_t vaddr, void *udata)
{
    (void)vcpu;
    (void)udata;
    if (!w.open || vaddr < LAN9118_BASE || vaddr >= LAN9118_BASE + LAN9118_WINDOW) {
        return;
    }
    uint32_t offset = (uint32_t)(vaddr - LAN9118_BASE);
    uint64_t at = w.instructions - 1;
    enum lan_access access = ACCESS_OTHER;
    if (qemu_plugin_mem_is_store(info)) {
        if (offset >= RX_DATA_FIFO_END && offset < TX_DATA_FIFO_END) {
            access = ACCESS_TX_DATA;
            if (w.last_access != ACCESS_TX_DATA) {
                w.tx_frames++;
                if (w.tx_first == NONE) {
                    w.tx_first = at;
                }
            }
            w.tx_last = at;
        }
    } else if (offset < RX_DATA_FIFO_END) {
        w.rx_data = at;
    } else if (offset == RX_STATUS_FIFO) {
        w.rx_frames++;
        if (w.rx_status == NONE) {
            w.rx_status = at;
        }
    }
    w.last_access = access;
}

static void on_idle(qemu_plugin_id_t id, unsigned int vcpu)
{
    (void)id;
    (void)vcpu;
    if (w.open) {
        close_window();
    }
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t pc = qemu_plugin_insn_vaddr(insn);
        /* Callbacks of one instruction run in the order they were registered. */
        if (pc == irq_pc) {
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_irq, QEMU_PLUGIN_CB_NO_REGS, NULL);
        }
        if (pc == tick_pc) {
            qemu_plugin_register_vcpu_insn_exec_cb(insn, on_tick, QEMU_PLUGIN_CB_NO_REGS, NULL);
        }
        qemu_plugin_register_vcpu_insn_exec_cb(insn, on_insn, QEMU_PLUGIN_CB_NO_REGS, (void *)(uintptr_t)pc);
        qemu_plugin_register_vcpu_mem_cb(insn, on_mem, QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_MEM_RW, NULL);
    }
}

static void on_quit(qemu_plugin_id_t id, void *udata)
{
    (void)id;
    (void)udata;
    if (w.open) {
        close_window();
    }
    fclose(out);
    out = NULL;
}

static bool parse_address(const char *text, uint64_t *value)
{
    char *end;
    *value = strtoull(text, &end, 0);
    return *text && !*end;
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                                               int argc, char **argv)
{
    (void)info;
    const char *out_path = NULL;
    for (int i = 0; i < argc; i++) {
        const char *arg = argv[i];
        bool ok = true;
        if (strncmp(arg, "irq=", 4) == 0) {
            ok = parse_address(arg + 4, &irq_pc);
        } else if (strncmp(arg, "tick=", 5) == 0) {
            ok = parse_address(arg + 5, &tick_pc);
        } else if (strncmp(arg, "ctl=", 4) == 0) {
            ctl_fd = open(arg + 4, O_RDONLY | O_CLOEXEC);
            ok = ctl_fd >= 0;
        } else if (strncmp(arg, "out=", 4) == 0) {
            out_path = arg + 4;
        } else if (strncmp(arg, "live=", 5) == 0) {
            live = strcmp(arg + 5, "1") == 0;
            ok = live || strcmp(arg + 5, "0") == 0;
        } else {
            ok = false;
        }
        if (!ok) {
            fprintf(stderr, "request_windows: bad argument or file: %s\n", arg);
            return -1;
        }
    }
    if (irq_pc == NONE || !out_path) {
        qemu_plugin_outs("request_windows: needs irq=ADDRESS and out=FILE\n");
        return -1;
    }
    /* Thumb: the vector holds the address with bit 0 set; instructions sit at the even one. */
    irq_pc &= ~(uint64_t)1;
    if (tick_pc != NONE) {
        tick_pc &= ~(uint64_t)1;
    }
    out = fopen(out_path, "w");
    trace = malloc(TRACE_MAX * sizeof *trace);
    if (!out || !trace) {
        fprintf(stderr, "request_windows: cannot write %s\n", out_path);
        return -1;
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_vcpu_idle_cb(id, on_idle);
    qemu_plugin_register_atexit_cb(id, on_quit, NULL);
    return 0;
}
