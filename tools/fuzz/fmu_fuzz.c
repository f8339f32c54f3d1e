/* fmu_fuzz: random FMI 2.0 call sequences against a cedra FMU compiled in (no dlopen), normally under
 * AddressSanitizer + UndefinedBehaviorSanitizer. Built and run by python/cedra/fmu/fuzz.py
 * (`python -m cedra fuzz <scene|file.fmu>`), which compiles this file with every C file in the FMU's sources/.
 *
 * Modes:
 *   fuzz (default)   --seed S --sequences N [--seconds T] [--call-limit T] [--keep-going] [--trace]
 *                    sequence k uses the PRNG seeded with S + k, so `--seed S+k --sequences 1 --trace` replays it.
 *   leak cycles      --cycles N      instantiate/setup/init/step/state/free cycles, also the failure paths
 *                                    (allocation failures, refused instantiations); run with LeakSanitizer or
 *                                    valgrind, which judge the result at exit.
 *   threads          --threads N [--steps M]   N scenarios (different torques, and grids when several
 *                                    --resources are given) run one after another, then in N threads at once;
 *                                    outputs at every communication point and the serialized end state must be
 *                                    bit-identical.
 * Common: --resources URI (repeatable; heightmap FMUs read resources/heightmap.txt from the first).
 *
 * Invariants of the fuzz mode (a violation prints "FINDING seed=S call=K inst=I: ..." and the exit status is 1):
 *   (a) no sanitizer report (the sanitizer aborts the process; a death callback prints "SANITIZER seed=S call=K"
 *       first so the runner knows which call it was);
 *   (b) every status is in 0..4, and fmi2Fatal only when an allocation failed during the call;
 *   (c) every Real read with status OK is finite (variables and fmi2LastSuccessfulTime);
 *   (d) a DoStep(t, h) returning fmi2OK has t + h > t, fmi2LastSuccessfulTime == t + h exactly, and the Integer
 *       output solver.steps increased (the step integrated something); afterwards every Real output is finite;
 *   (e) a call on an instance that returns fmi2Error leaves the instance's serialized state byte for byte as it
 *       was. No call is exempt: the FMI 2.0 standard lets fmi2Error leave the instance in the state before the
 *       call ("the function call had no effect") for misuse, and for ExitInitializationMode an error must not
 *       leave a half-computed start either;
 *   (f) every non-OK status of a call on an instance with a logger reached the logger with a non-empty message
 *       (also a failed fmi2Instantiate with a logger), through that instance's componentEnvironment;
 *   (g) fmi2Instantiate with a wrong GUID, a wrong fmuType or without allocate/free functions returns NULL;
 *   (h) no call runs longer than --call-limit seconds (default 10): the issue asks for a bounded cost per call.
 *
 * Planted bugs (compile with -D, used by the tests to show the checks can fail):
 *   FUZZ_PLANT_NOOP_STEP   fmi2DoStep returns fmi2OK without calling the FMU (d)
 *   FUZZ_PLANT_OVERFLOW    fmi2GetReal writes one value past the caller's array (a)
 *   FUZZ_PLANT_PARTIAL_SET fmi2SetReal of a vector with a bad entry first sets the good entries one by one (e)
 *   FUZZ_PLANT_LEAK        the leak cycles forget to free one deserialized FMU state per cycle
 */
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "fmi2Functions.h"

/* the generated table defines static arrays the glue uses and this file partly does not */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-const-variable"
#pragma GCC diagnostic ignored "-Wunused-variable"
#include "cedra_vars.h"
#pragma GCC diagnostic pop
#include "glue.h"      /* the FMU's own state struct, to name what a refused call changed */

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/common_interface_defs.h>
#endif

#define MAX_INST 3
#define POOL 6          /* FMU state handles kept per sequence */
#define BUFS 4          /* serialized states kept per sequence */
#define MAX_DOSTEPS 24  /* per sequence: keeps a sequence cheap */
#define MAX_RES 8

/* ------------------------------------------------------------------------------------------------ options */

static struct {
    unsigned long long seed;
    long sequences;
    double seconds;
    double call_limit;
    int keep_going;
    int trace;
    long cycles;
    int threads;
    int steps;
    const char *res[MAX_RES];
    int nres;
} opt = {1, 100, 0.0, 10.0, 0, 0, 0, 0, 100, {0}, 0};

/* ---------------------------------------------------------------------------------------------- PRNG */

static uint64_t rng;

static uint64_t splitmix64(uint64_t *x) {
    uint64_t z = (*x += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}
static uint64_t rnd(void) { return splitmix64(&rng); }
static double urand(void) { return (double)(rnd() >> 11) * 0x1.0p-53; }
static int irand(int n) { return n > 0 ? (int)(rnd() % (uint64_t)n) : 0; }
static int chance(double p) { return urand() < p; }
static double loguniform(double lo, double hi) { return exp(log(lo) + urand() * (log(hi) - log(lo))); }

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* ------------------------------------------------------------------------------------- variables by kind */

static const cedra_var *var_named(const char *name) {
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (strcmp(CEDRA_VARS[i].name, name) == 0) return &CEDRA_VARS[i];
    return NULL;
}

static const cedra_var *var_of(int kind, int index) {
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].kind == kind && CEDRA_VARS[i].index == index) return &CEDRA_VARS[i];
    return NULL;
}

static unsigned int max_vr(void) {
    unsigned int m = 0;
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].vr > m) m = CEDRA_VARS[i].vr;
    return m;
}

/* a random variable of `type` (any type if < 0), settable only (want_set) or any; solver settings only when
 * allowed or when nothing else fits (the only settable Integer is solver.method) */
static const cedra_var *pick_var(int type, int want_set, int allow_solver) {
    const cedra_var *cand[CEDRA_NVARS];
    for (int pass = 0; pass < 2; pass++) {
        int n = 0;
        for (int i = 0; i < CEDRA_NVARS; i++) {
            const cedra_var *v = &CEDRA_VARS[i];
            if ((type >= 0 && v->type != type) || (want_set && v->causality == CEDRA_OUTPUT)) continue;
            if (!allow_solver && !pass && v->kind == CEDRA_K_SOLVER) continue;
            cand[n++] = v;
        }
        if (n) return cand[irand(n)];
    }
    return NULL;
}

/* ------------------------------------------------------------------------------------------ random values */

static const double SPECIAL[] = {0.0, -0.0, 1e300, -1e300, 1e-300, -1e-300, HUGE_VAL, -HUGE_VAL, 1.0, -1.0};

static double clamp_in(const cedra_var *v, double d) {
    if (d < v->min) d = v->min;
    if (d > v->max) d = v->max;
    if (v->min_exclusive && d <= v->min) d = isfinite(v->min) ? v->min + fabs(v->min) * 1e-6 + 1e-12 : 0.0;
    return d;
}

/* a plausible value: near the start value, inside the bounds */
static double sane_real(const cedra_var *v) {
    if (v->kind == CEDRA_K_SOLVER && v->index == 2) {   /* h_max: cheap for RK4, now and then absurd */
        static const double H[] = {1e-3, 2e-3, 5e-3, 1e-2, 2e-2}, ABSURD[] = {1e-300, 5e-324, 1e300, 1e-9};
        return chance(0.06) ? ABSURD[irand(4)] : H[irand(5)];
    }
    if (v->kind == CEDRA_K_SOLVER && v->index == 1) return chance(0.05) ? (chance(0.5) ? 1e-300 : 1e300)
                                                                       : loguniform(1e-8, 1e-3);
    if (v->kind == CEDRA_K_INP && v->start == 0.0) return clamp_in(v, 3.0 * (2.0 * urand() - 1.0));   /* torques */
    if (isfinite(v->min) && isfinite(v->max)) return v->min + urand() * (v->max - v->min);
    double s = v->start, d = s + (s != 0.0 ? s : 0.1) * 0.2 * (2.0 * urand() - 1.0);
    return clamp_in(v, d);
}

/* anything: in range, at the bounds, just outside, non-finite, extreme */
static double wild_real(const cedra_var *v) {
    switch (irand(14)) {
        case 0: case 1: case 2: return sane_real(v);
        case 3: return v->start;
        case 4: return isfinite(v->min) ? v->min : -1e300;
        case 5: return isfinite(v->max) ? v->max : 1e300;
        case 6: return isfinite(v->min) ? nextafter(v->min, -HUGE_VAL) : -HUGE_VAL;
        case 7: return isfinite(v->max) ? nextafter(v->max, HUGE_VAL) : HUGE_VAL;
        case 8: return NAN;
        case 9: return -NAN;
        case 10: { uint64_t b = rnd(); double d; memcpy(&d, &b, sizeof d); return d; }   /* any bit pattern */
        case 11: return v->start * (1.0 + 1e-12);
        default: return SPECIAL[irand((int)(sizeof SPECIAL / sizeof SPECIAL[0]))];
    }
}

static int clamp_int32(long long x) { return x > INT32_MAX ? INT32_MAX : x < INT32_MIN ? INT32_MIN : (int)x; }

static int wild_int(const cedra_var *v) {
    switch (irand(9)) {
        case 0: case 1: case 2:
            return isfinite(v->min) && isfinite(v->max) ? (int)v->min + irand((int)(v->max - v->min) + 1)
                                                        : (int)v->start;
        /* just outside the range, where an fmi2Integer can be (a bound at INT32_MIN/MAX has no outside) */
        case 3: return isfinite(v->min) ? clamp_int32((long long)v->min - 1) : -1;
        case 4: return isfinite(v->max) ? clamp_int32((long long)v->max + 1) : 3;
        case 5: return INT32_MIN;
        case 6: return INT32_MAX;
        case 7: return (int)(int32_t)(uint32_t)rnd();
        default: return 0;
    }
}

static int wild_bool(void) {
    static const int B[] = {0, 1, 0, 1, 2, -1, INT32_MIN, 255};
    return B[irand(8)];
}

/* --------------------------------------------------------------------------------------------- allocator */

/* Allocation failures are injected per call (the callbacks have no environment argument): 0 none, k > 0 the
 * k-th allocation of the call fails, -1 every allocation fails. fmi2Fatal is legitimate only after one did. */
static int fail_at, alloc_count, alloc_failed;

static void *fuzz_calloc(size_t n, size_t size) {
    if (fail_at != 0) {
        alloc_count++;
        if (fail_at < 0 || alloc_count == fail_at) {
            alloc_failed = 1;
            return NULL;
        }
    }
    return calloc(n, size);
}

/* ------------------------------------------------------------------------------------- findings, tracing */

enum ph { P_NONE, P_INST, P_INIT, P_STEP, P_FAILED, P_TERM, P_UNKNOWN };

typedef struct slot {
    int id;
    fmi2Component c;
    enum ph phase;       /* what the fuzzer believes (drives the choice of "natural" calls only) */
    double t;            /* believed current time */
    int t_known;
    fmi2FMUstate scratch;  /* the handle the state snapshots of check (e) reuse */
    fmi2CallbackFunctions cb;  /* lives as long as the instance (an FMU may keep the pointer) */
    /* logger bookkeeping for the current call */
    int msgs_bad;          /* messages with a status other than OK and a non-empty text */
    char last_msg[256];
} slot;

static slot slots[MAX_INST];
static int nslots;
static slot *cur;                 /* the instance the current call addresses (NULL: none) */
static unsigned long long cur_seed;
static long call_idx, total_calls, total_checks, total_findings, total_steps_ok;
static int seq_failed;
static char desc[512];
static char alarm_line[768];
static int in_sequence;

static void finding(const char *fmt, ...) {
    char text[1536];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    printf("FINDING seed=%llu call=%ld inst=%d: %s [in %s]\n", cur_seed, call_idx, cur ? cur->id : -1, text, desc);
    fflush(stdout);
    total_findings++;
    seq_failed = 1;
}

static void on_alarm(int sig) {
    (void)sig;
    ssize_t w = write(1, alarm_line, strlen(alarm_line));
    (void)w;
    _exit(1);
}

#if defined(__SANITIZE_ADDRESS__)
static void on_sanitizer_death(void) {
    if (!in_sequence) return;
    printf("SANITIZER seed=%llu call=%ld inst=%d: %s\n", cur_seed, call_idx, cur ? cur->id : -1, desc);
    fflush(stdout);
}
#endif

static void arm(double seconds) {
    struct itimerval it;
    memset(&it, 0, sizeof it);
    it.it_value.tv_sec = (time_t)seconds;
    it.it_value.tv_usec = (suseconds_t)((seconds - floor(seconds)) * 1e6);
    setitimer(ITIMER_REAL, &it, NULL);
}

static const char *STATUS_NAMES[] = {"OK", "Warning", "Discard", "Error", "Fatal", "Pending"};
static const char *status_name(int s) { return s >= 0 && s <= 5 ? STATUS_NAMES[s] : "(out of range)"; }

static int check_calls;   /* >0 while the fuzzer's own checking calls run (not counted, not traced) */

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    char text[4096];
    if (!message) {
        finding("(f) logger: message is NULL");
        return;
    }
    va_list ap;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message, ap);   /* formats like an importer does: a stray % would show here */
    va_end(ap);
    if (!name || !category) finding("(f) logger: instanceName or category is NULL (message %s)", text);
    if ((int)status < 0 || (int)status > 4)
        finding("(b) logger: status %d out of range (message %s)", (int)status, text);
    if (opt.trace && !check_calls)
        printf("      log %s %s: %s\n", status_name((int)status), category ? category : "(NULL)", text);
    slot *s = cur;
    if (s && env != (fmi2ComponentEnvironment)s)
        finding("(f) logger: componentEnvironment %p is not the addressed instance's (%p): %s", env, (void *)s, text);
    if (s && status != fmi2OK && text[0]) {
        s->msgs_bad++;
        snprintf(s->last_msg, sizeof s->last_msg, "%.255s", text);
    }
}

static const fmi2CallbackFunctions CALLBACKS_TEMPLATE = {logger, fuzz_calloc, free, NULL, NULL};

/* ------------------------------------------------------------------------------ state snapshots for (e) */

typedef cedra_state mirror_state;       /* glue.h, from the FMU's sources/ */

static void element_name(const char *field, int i, char *out, size_t len) {
    const cedra_var *v = NULL;
    if (strcmp(field, "inp") == 0) v = var_of(CEDRA_K_INP, i);
    else if (strcmp(field, "par") == 0) v = var_of(CEDRA_K_PAR, i);
    else if (strcmp(field, "q_start") == 0) v = var_of(CEDRA_K_Q_START, i);
    else if (strcmp(field, "u_start") == 0) v = var_of(CEDRA_K_U_START, i);
    if (v) snprintf(out, len, "%s[%d] (%s)", field, i, v->name);
    else if (strcmp(field, "y") == 0 && i < CEDRA_NY) snprintf(out, len, "y[%d] (%s)", i, CEDRA_Y_NAMES[i]);
    else if (strcmp(field, "x") == 0 && i < CEDRA_NQ) snprintf(out, len, "x[%d] (q %s)", i, CEDRA_Q_NAMES[i]);
    else if (strcmp(field, "x") == 0 && i < 2 * CEDRA_NQ)
        snprintf(out, len, "x[%d] (speed %s)", i, CEDRA_Q_NAMES[i - CEDRA_NQ]);
    else snprintf(out, len, "%s[%d]", field, i);
}

/* names the changed fields (at most 4) */
static void describe_change(const unsigned char *a, const unsigned char *b, size_t n, char *out, size_t len) {
    size_t k = 0;
    int shown = 0;
    out[0] = '\0';
    if (n != sizeof(mirror_state)) {
        for (size_t i = 0; i < n && shown < 4; i++)
            if (a[i] != b[i]) {
                k += (size_t)snprintf(out + k, len - k, "%sbyte %zu: %u -> %u", shown ? "; " : "", i, a[i], b[i]);
                shown++;
                if (k >= len) return;
            }
        return;
    }
    const mirror_state *p = (const mirror_state *)(const void *)a, *q = (const mirror_state *)(const void *)b;
#define INT_FIELD(f)                                                                                              \
    if (p->f != q->f && shown < 4 && k < len) {                                                                   \
        k += (size_t)snprintf(out + k, len - k, "%s" #f ": %ld -> %ld", shown ? "; " : "", (long)p->f, (long)q->f); \
        shown++;                                                                                                  \
    }
#define DBL_FIELD(f, name)                                                                                        \
    if (memcmp(&p->f, &q->f, sizeof(double)) != 0 && shown < 4 && k < len) {                                     \
        k += (size_t)snprintf(out + k, len - k, "%s%s: %.17g -> %.17g", shown ? "; " : "", name, p->f, q->f);     \
        shown++;                                                                                                  \
    }
#define ARR_FIELD(f, label, cnt)                                                                                  \
    for (int i = 0; i < (cnt); i++) {                                                                             \
        char nm[128];                                                                                             \
        element_name(label, i, nm, sizeof nm);                                                                    \
        DBL_FIELD(f[i], nm)                                                                                       \
    }
    INT_FIELD(magic) INT_FIELD(size) INT_FIELD(phase) INT_FIELD(terminated) INT_FIELD(outputs_valid)
    if (memcmp(p->guid, q->guid, sizeof p->guid) != 0 && shown < 4 && k < len) {
        k += (size_t)snprintf(out + k, len - k, "%sguid", shown ? "; " : "");
        shown++;
    }
    DBL_FIELD(time, "time") DBL_FIELD(start_time, "start_time") DBL_FIELD(last_good_time, "last_good_time")
    ARR_FIELD(inp, "inp", CEDRA_NI) ARR_FIELD(par, "par", CEDRA_NP) ARR_FIELD(y, "y", CEDRA_NY)
#if CEDRA_CONTROLLER
    ARR_FIELD(b.xd, "xd", CEDRA_ND) INT_FIELD(b.taken)
#else
    ARR_FIELD(b.x, "x", CEDRA_NX) ARR_FIELD(b.q_start, "q_start", CEDRA_NQ) ARR_FIELD(b.u_start, "u_start", CEDRA_NQ)
    INT_FIELD(b.settle) INT_FIELD(b.tol_explicit) INT_FIELD(b.solver.method) DBL_FIELD(b.solver.tol, "solver.tol")
    DBL_FIELD(b.solver.h_max, "solver.h_max") INT_FIELD(b.solver.max_steps)
    DBL_FIELD(b.solver.max_wall, "solver.max_wall_time") INT_FIELD(b.stats.steps) INT_FIELD(b.stats.rejected)
    INT_FIELD(b.stats.rhs_evals) INT_FIELD(b.stats.jac_evals) DBL_FIELD(b.stats.h_next, "stats.h_next")
#endif
    if (!shown) snprintf(out, len, "padding bytes only");
#undef INT_FIELD
#undef DBL_FIELD
#undef ARR_FIELD
}

static size_t state_size;   /* from fmi2SerializedFMUstateSize, the same for every instance */

/* serialized state of s into *buf (malloc'd); 0, or 1 if the instance would not give it */
static int snapshot(slot *s, unsigned char **buf, size_t *n) {
    size_t sz = 0;
    *buf = NULL;
    if (!s || !s->c) return 1;
    check_calls++;
    total_checks += 3;
    int bad = fmi2GetFMUstate(s->c, &s->scratch) != fmi2OK || !s->scratch ||
              fmi2SerializedFMUstateSize(s->c, s->scratch, &sz) != fmi2OK || sz == 0;
    if (!bad) {
        *buf = (unsigned char *)malloc(sz);
        bad = fmi2SerializeFMUstate(s->c, s->scratch, (fmi2Byte *)*buf, sz) != fmi2OK;
    }
    check_calls--;
    if (bad) {
        free(*buf);
        *buf = NULL;
        return 1;
    }
    *n = sz;
    state_size = sz;
    return 0;
}

/* ------------------------------------------------------------------------------------------- call frame */

static unsigned char *snap_before;
static size_t snap_before_n;
static int cur_fail_alloc;

/* Before a call: name it (trace, findings, the alarm's line), take the (e) snapshot, reset the logger's count,
 * arm the per-call time limit. */
static void begin(slot *s, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(desc, sizeof desc, fmt, ap);
    va_end(ap);
    call_idx++;
    total_calls++;
    cur = s;
    free(snap_before);
    snap_before = NULL;
    if (s && s->c) snapshot(s, &snap_before, &snap_before_n);
    if (s) {
        s->msgs_bad = 0;
        s->last_msg[0] = '\0';
    }
    snprintf(alarm_line, sizeof alarm_line, "FINDING seed=%llu call=%ld inst=%d: (h) did not return within %g s "
             "(the issue asks for a bounded cost per call) [in %s]\n", cur_seed, call_idx, s ? s->id : -1,
             opt.call_limit, desc);
    if (opt.trace) {
        printf("  #%ld inst %d: %s\n", call_idx, s ? s->id : -1, desc);
        fflush(stdout);
    }
    alloc_count = alloc_failed = 0;
    fail_at = cur_fail_alloc;
    arm(opt.call_limit);
}

/* After a call on s (s->c the component that was passed; NULL: no instance to check): invariants (b), (e), (f). */
static fmi2Status end(slot *s, fmi2Component passed, fmi2Status st) {
    arm(0.0);
    fail_at = 0;
    if (opt.trace) printf("      -> %s\n", status_name((int)st));
    if ((int)st < 0 || (int)st > 4) finding("(b) status %d is not in 0..4", (int)st);
    if (st == fmi2Fatal && !alloc_failed) finding("(b) fmi2Fatal although no allocation failed");
    if (!passed || !s) return st;
    if (st != fmi2OK && s->msgs_bad == 0)
        finding("(f) status %s without a logged message", status_name((int)st));
    if (st == fmi2Error && snap_before) {
        unsigned char *after = NULL;
        size_t n = 0;
        if (snapshot(s, &after, &n) == 0) {
            if (n != snap_before_n || memcmp(after, snap_before, n) != 0) {
                char what[1024];
                describe_change(snap_before, after, n < snap_before_n ? n : snap_before_n, what, sizeof what);
                finding("(e) returned fmi2Error but changed the instance: %s (logged: %s)", what, s->last_msg);
            }
            free(after);
        }
    }
    return st;
}

/* ------------------------------------------------------------------------------------- sequence state */

typedef struct {
    fmi2FMUstate h;
    enum ph phase;
    double t;
    int t_known;
} pooled;

typedef struct {
    unsigned char *b;
    size_t n;
    enum ph phase;
    double t;
} sbuf;

static pooled pool[POOL];
static int npool;
static sbuf bufs[BUFS];
static int nbufs;
static int dosteps;

static slot *live_slot(void) {
    for (int i = 0; i < nslots; i++)
        if (slots[i].c) return &slots[i];
    return NULL;
}

static int nlive(void) {
    int n = 0;
    for (int i = 0; i < nslots; i++) n += slots[i].c != NULL;
    return n;
}

static void free_pool_via(slot *s) {
    for (int i = 0; i < npool; i++) {
        begin(s, "fmi2FreeFMUstate(pool %d) [cleanup]", i);
        end(s, s->c, fmi2FreeFMUstate(s->c, &pool[i].h));
    }
    npool = 0;
}

/* frees s's instance: its scratch state first, the pool too when it is the last live instance */
static void free_slot(slot *s) {
    if (!s->c) return;
    if (nlive() == 1 && npool > 0) free_pool_via(s);
    if (s->scratch) {   /* after the pool: freeing the pool takes snapshots into it */
        cur = s;
        check_calls++;
        fmi2FreeFMUstate(s->c, &s->scratch);
        check_calls--;
        s->scratch = NULL;
    }
    begin(NULL, "fmi2FreeInstance(inst %d)", s->id);
    fmi2FreeInstance(s->c);
    end(NULL, NULL, fmi2OK);
    s->c = NULL;
    s->phase = P_NONE;
}

/* ---------------------------------------------------------------------------------------------- calls */

static double real_status(slot *s, int *ok) {
    fmi2Real v = NAN;
    cur = s;
    check_calls++;
    total_checks++;
    *ok = fmi2GetRealStatus(s->c, fmi2LastSuccessfulTime, &v) == fmi2OK;
    check_calls--;
    return v;
}

static int read_steps(slot *s, long *steps) {
    const cedra_var *v = var_of(CEDRA_K_STAT, 0);
    fmi2Integer n = 0;
    if (!v) return 1;
    fmi2ValueReference vr = v->vr;
    cur = s;
    check_calls++;
    total_checks++;
    int bad = fmi2GetInteger(s->c, &vr, 1, &n) != fmi2OK;
    check_calls--;
    *steps = n;
    return bad;
}

static fmi2Component comp_of(slot *s, int wild) { return wild && chance(0.04) ? NULL : s->c; }

static void c_instantiate(slot *s, int wild) {
    if (s->c) free_slot(s);
    fmi2CallbackFunctions cb = CALLBACKS_TEMPLATE;
    cb.componentEnvironment = s;
    char name[32], guid[128];
    const char *nm = name, *gd = guid, *res = opt.nres ? opt.res[0] : "file:///nonexistent/resources";
    fmi2Type type = fmi2CoSimulation;
    int must_fail = 0, variant = wild ? irand(17) : 0;
    snprintf(name, sizeof name, "inst%d", s->id);
    snprintf(guid, sizeof guid, "%s", CEDRA_GUID);
    cur_fail_alloc = 0;
    switch (variant) {
        case 1: must_fail = 1; break;
        case 2: cb.logger = NULL; break;
        case 3: cb.allocateMemory = NULL; must_fail = 1; break;
        case 4: cb.freeMemory = NULL; must_fail = 1; break;
        case 5: nm = NULL; break;
        case 6: nm = ""; break;
        case 7: gd = NULL; must_fail = 1; break;
        case 8: guid[1 + irand((int)strlen(guid) - 2)] ^= 0x01; must_fail = 1; break;
        case 9: guid[strlen(guid) / 2] = '\0'; must_fail = 1; break;
        case 10: type = fmi2ModelExchange; must_fail = 1; break;
        case 11: type = (fmi2Type)7; must_fail = 1; break;
        case 12: res = NULL; break;
        case 13: res = chance(0.5) ? "http://example.com/resources" : "file://otherhost/resources"; break;
        case 14: res = "file:///nonexistent/dir/resources"; break;
        case 15: cur_fail_alloc = 1 + irand(6); break;   /* one of the first allocations fails */
        default: break;
    }
    s->cb = cb;
    const fmi2CallbackFunctions *fns = variant == 1 ? NULL : &s->cb;
    begin(s, "fmi2Instantiate(variant %d, name %s, guid %s, resources %s%s)", variant, nm ? nm : "NULL",
          gd ? gd : "NULL", res ? res : "NULL", cur_fail_alloc ? ", an allocation fails" : "");
    fmi2Component c = fmi2Instantiate(nm, type, gd, res, fns, chance(0.5), chance(0.2));
    cur_fail_alloc = 0;
    end(s, NULL, fmi2OK);
    if (opt.trace) printf("      -> %s\n", c ? "instance" : "NULL");
    if (c && must_fail) finding("(g) fmi2Instantiate variant %d returned an instance", variant);
    if (!c && fns && fns->logger && s->msgs_bad == 0)
        finding("(f) fmi2Instantiate returned NULL without a logged message");
    s->c = c;
    s->phase = c ? P_INST : P_NONE;
    s->t = 0.0;
    s->t_known = 1;
    s->scratch = NULL;
}

static void c_free(slot *s, int wild) {
    if (wild && chance(0.1)) {
        begin(NULL, "fmi2FreeInstance(NULL)");
        fmi2FreeInstance(NULL);
        end(NULL, NULL, fmi2OK);
        return;
    }
    free_slot(s);
}

static void c_setup(slot *s, int wild) {
    static const double T[] = {0.0, 1.0, -5.0, 1e300, -1e300, 1e-300, NAN, HUGE_VAL, -HUGE_VAL, 1e9};
    double start = 0.0, stop = 10.0, tol = 1e-6;
    fmi2Boolean tol_def = chance(0.5), stop_def = chance(0.5);
    if (wild) {
        start = chance(0.5) ? T[irand(10)] : 10.0 * urand();
        stop = chance(0.3) ? T[irand(10)] : start + 10.0 * urand();
        tol = chance(0.5) ? T[irand(10)] : loguniform(1e-10, 1e-2);
    } else if (chance(0.3)) {
        start = 10.0 * urand();
        stop = start + 20.0;
    }
    fmi2Component c = comp_of(s, wild);
    begin(s, "fmi2SetupExperiment(tolDefined %d, tol %.17g, start %.17g, stopDefined %d, stop %.17g)", tol_def, tol,
          start, stop_def, stop);
    fmi2Status st = end(s, c, fmi2SetupExperiment(c, tol_def, tol, start, stop_def, stop));
    if (st == fmi2OK && c) s->t = start, s->t_known = 1;
}

static void c_simple(slot *s, int wild, int which) {
    static const char *NAMES[] = {"fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate",
                                  "fmi2Reset", "fmi2CancelStep"};
    fmi2Component c = comp_of(s, wild);
    begin(s, "%s()", NAMES[which]);
    fmi2Status st;
    switch (which) {
        case 0: st = fmi2EnterInitializationMode(c); break;
        case 1: st = fmi2ExitInitializationMode(c); break;
        case 2: st = fmi2Terminate(c); break;
        case 3: st = fmi2Reset(c); break;
        default: st = fmi2CancelStep(c); break;
    }
    end(s, c, st);
    if (st != fmi2OK || !c) return;
    if (which == 0) s->phase = P_INIT;
    if (which == 1) s->phase = P_STEP;
    if (which == 2) s->phase = P_TERM;
    if (which == 3) s->phase = P_INST, s->t = 0.0, s->t_known = 1;
}

/* value references for a set/get of `type`: mostly variables of that type, sometimes wrong ones */
static void pick_vrs(fmi2ValueReference *vr, size_t n, int type, int want_set, int wild) {
    for (size_t k = 0; k < n; k++) {
        const cedra_var *v = NULL;
        int r = wild ? irand(100) : 0;
        if (type > CEDRA_BOOLEAN) v = r < 90 ? pick_var(-1, 0, 1) : NULL;   /* String: there are none */
        else if (r < 75) v = pick_var(type, want_set, wild ? chance(0.3) : chance(0.1));
        else if (r < 85) v = pick_var(type, 0, 1);             /* outputs too */
        else if (r < 92) v = pick_var(-1, 0, 1);               /* any type */
        if (v) vr[k] = v->vr;
        else vr[k] = r < 96 ? max_vr() + 1 + (unsigned)irand(10) : (chance(0.5) ? 0xFFFFFFFFu : 0x80000000u);
    }
}

static const cedra_var *var_by_vr(fmi2ValueReference vr) {
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].vr == vr) return &CEDRA_VARS[i];
    return NULL;
}

static size_t pick_n(int wild) {
    int r = irand(100);
    if (wild && r < 6) return 0;
    if (r < 60) return 1;
    return 2 + (size_t)irand(3);
}

#ifdef FUZZ_PLANT_PARTIAL_SET
/* the planted bug: an invalid vector is applied up to its first bad entry, then refused */
static fmi2Status planted_set_real(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    fmi2Status st = fmi2SetReal(c, vr, n, v);
    if (st == fmi2Error && c && vr && v)
        for (size_t k = 0; k < n; k++)
            if (fmi2SetReal(c, &vr[k], 1, &v[k]) != fmi2OK) break;
    return st;
}
#undef fmi2SetReal   /* the header's name macro: later calls go to the planted bug */
#define fmi2SetReal planted_set_real
#endif

#ifdef FUZZ_PLANT_OVERFLOW
static fmi2Status planted_get_real(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    fmi2Status st = fmi2GetReal(c, vr, n, v);
    if (st == fmi2OK && n > 0) v[n] = 0.0;   /* one past the caller's array */
    return st;
}
#undef fmi2GetReal
#define fmi2GetReal planted_get_real
#endif

static void c_set(slot *s, int wild, int type) {
    size_t n = pick_n(wild);
    /* exactly sized heap arrays: an FMU reading or writing past n is an ASan report */
    fmi2ValueReference *vr = n ? (fmi2ValueReference *)malloc(n * sizeof *vr) : NULL;
    void *val = NULL;
    int null_vr = wild && n > 0 && chance(0.04), null_val = wild && n > 0 && chance(0.04);
    pick_vrs(vr, n, type, 1, wild);
    char what[256] = "";
    size_t k0 = 0;
    if (type == CEDRA_REAL) {
        fmi2Real *v = n ? (fmi2Real *)malloc(n * sizeof *v) : NULL;
        for (size_t k = 0; k < n; k++) {
            const cedra_var *var = var_by_vr(vr[k]);
            v[k] = var ? (wild ? wild_real(var) : sane_real(var)) : 1.0;
            k0 += (size_t)snprintf(what + k0, k0 < sizeof what ? sizeof what - k0 : 0, "%s%u=%.17g", k ? ", " : "",
                                   vr[k], v[k]);
            if (k0 >= sizeof what) k0 = sizeof what - 1;
        }
        val = v;
    } else if (type == CEDRA_INTEGER) {
        fmi2Integer *v = n ? (fmi2Integer *)malloc(n * sizeof *v) : NULL;
        for (size_t k = 0; k < n; k++) {
            const cedra_var *var = var_by_vr(vr[k]);
            v[k] = var ? (wild ? wild_int(var) : (int)var->start) : 1;
            if (var && !wild && var->kind == CEDRA_K_SOLVER) v[k] = irand(SOLVER_N_METHODS);
            k0 += (size_t)snprintf(what + k0, k0 < sizeof what ? sizeof what - k0 : 0, "%s%u=%d", k ? ", " : "",
                                   vr[k], v[k]);
            if (k0 >= sizeof what) k0 = sizeof what - 1;
        }
        val = v;
    } else if (type == CEDRA_BOOLEAN) {
        fmi2Boolean *v = n ? (fmi2Boolean *)malloc(n * sizeof *v) : NULL;
        for (size_t k = 0; k < n; k++) {
            v[k] = wild ? wild_bool() : irand(2);
            k0 += (size_t)snprintf(what + k0, k0 < sizeof what ? sizeof what - k0 : 0, "%s%u=%d", k ? ", " : "",
                                   vr[k], v[k]);
            if (k0 >= sizeof what) k0 = sizeof what - 1;
        }
        val = v;
    } else {
        fmi2String *v = n ? (fmi2String *)malloc(n * sizeof *v) : NULL;
        for (size_t k = 0; k < n; k++) v[k] = chance(0.2) ? NULL : "a string";
        val = v;
    }
    static const char *FN[] = {"fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean", "fmi2SetString"};
    fmi2Component c = comp_of(s, wild);
    const fmi2ValueReference *pvr = null_vr ? NULL : vr;
    const void *pval = null_val ? NULL : val;
    begin(s, "%s(n %zu%s%s: %s)", FN[type], n, null_vr ? ", vr NULL" : "", null_val ? ", value NULL" : "", what);
    fmi2Status st;
    switch (type) {
        case CEDRA_REAL: st = fmi2SetReal(c, pvr, n, (const fmi2Real *)pval); break;
        case CEDRA_INTEGER: st = fmi2SetInteger(c, pvr, n, (const fmi2Integer *)pval); break;
        case CEDRA_BOOLEAN: st = fmi2SetBoolean(c, pvr, n, (const fmi2Boolean *)pval); break;
        default: st = fmi2SetString(c, pvr, n, (const fmi2String *)pval); break;
    }
    end(s, c, st);
    free(vr);
    free(val);
}

static void c_get(slot *s, int wild, int type) {
    size_t n = pick_n(wild);
    fmi2ValueReference *vr = n ? (fmi2ValueReference *)malloc(n * sizeof *vr) : NULL;
    int null_vr = wild && n > 0 && chance(0.04), null_val = wild && n > 0 && chance(0.04);
    pick_vrs(vr, n, type, 0, wild);
    static const size_t SZ[] = {sizeof(fmi2Real), sizeof(fmi2Integer), sizeof(fmi2Boolean), sizeof(fmi2String)};
    void *val = n ? malloc(n * SZ[type]) : NULL;
    char what[256] = "";
    size_t k0 = 0;
    for (size_t k = 0; k < n && k0 < sizeof what - 16; k++)
        k0 += (size_t)snprintf(what + k0, sizeof what - k0, "%s%u", k ? ", " : "", vr[k]);
    static const char *FN[] = {"fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean", "fmi2GetString"};
    fmi2Component c = comp_of(s, wild);
    const fmi2ValueReference *pvr = null_vr ? NULL : vr;
    void *pval = null_val ? NULL : val;
    begin(s, "%s(n %zu%s%s: vr %s)", FN[type], n, null_vr ? ", vr NULL" : "", null_val ? ", value NULL" : "", what);
    fmi2Status st;
    switch (type) {
        case CEDRA_REAL: st = fmi2GetReal(c, pvr, n, (fmi2Real *)pval); break;
        case CEDRA_INTEGER: st = fmi2GetInteger(c, pvr, n, (fmi2Integer *)pval); break;
        case CEDRA_BOOLEAN: st = fmi2GetBoolean(c, pvr, n, (fmi2Boolean *)pval); break;
        default: st = fmi2GetString(c, pvr, n, (fmi2String *)pval); break;
    }
    end(s, c, st);
    if (st == fmi2OK && type == CEDRA_REAL && pval)
        for (size_t k = 0; k < n; k++)
            if (!isfinite(((fmi2Real *)val)[k])) {
                const cedra_var *v = var_by_vr(vr[k]);
                finding("(c) fmi2GetReal returned OK with %s = %g", v ? v->name : "?", ((fmi2Real *)val)[k]);
            }
    if (st == fmi2OK && type == 3 && pval)
        for (size_t k = 0; k < n; k++)
            if (!((fmi2String *)val)[k]) finding("(c) fmi2GetString returned OK with a NULL string");
    free(vr);
    free(val);
}

/* every Real output finite (after an OK DoStep) */
static void check_outputs(slot *s) {
    fmi2ValueReference vr[CEDRA_NVARS];
    fmi2Real v[CEDRA_NVARS];
    size_t n = 0;
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].causality == CEDRA_OUTPUT && CEDRA_VARS[i].type == CEDRA_REAL) vr[n++] = CEDRA_VARS[i].vr;
    check_calls++;
    total_checks++;
    fmi2Status st = fmi2GetReal(s->c, vr, n, v);
    check_calls--;
    if (st != fmi2OK) {
        finding("(d) reading the outputs after an OK DoStep returned %s", status_name((int)st));
        return;
    }
    for (size_t k = 0; k < n; k++)
        if (!isfinite(v[k])) finding("(c) output %s = %g after an OK DoStep", var_by_vr(vr[k])->name, v[k]);
}

#ifdef FUZZ_PLANT_NOOP_STEP
static fmi2Status planted_do_step(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean b) {
    (void)t, (void)h, (void)b;
    return c ? fmi2OK : fmi2Error;   /* the planted bug: OK without stepping */
}
#undef fmi2DoStep
#define fmi2DoStep planted_do_step
#endif

static void c_dostep(slot *s, int wild) {
    static const double H[] = {0.0, -0.0, -0.01, NAN, HUGE_VAL, -HUGE_VAL, 1e300, 1e-300, 1e-12, 0.5, 1.0, 5e-324};
    int ok = 1;
    if (!s->t_known && s->c) {
        double t = real_status(s, &ok);
        if (ok) s->t = t, s->t_known = 1;
    }
    double t = s->t, h = loguniform(1e-4, 0.05);
    if (chance(wild ? 0.25 : 0.03)) h = H[irand((int)(sizeof H / sizeof H[0]))];
    if (wild && chance(0.15)) {
        switch (irand(6)) {
            case 0: t = t + 1e-3; break;
            case 1: t = t - 1e-3; break;
            case 2: t = NAN; break;
            case 3: t = t * (1.0 + 1e-12) + 1e-13; break;   /* inside the glue's tolerance */
            case 4: t = 0.0; break;
            default: t = HUGE_VAL; break;
        }
    }
    long steps0 = 0;
    int have_steps = s->c && s->phase == P_STEP && read_steps(s, &steps0) == 0;
    fmi2Component c = comp_of(s, wild);
    int nosetprior = chance(0.5);
    begin(s, "fmi2DoStep(t %.17g, h %.17g, noSetPrior %d) [solver.steps before: %ld]", t, h, nosetprior, steps0);
    fmi2Status st = end(s, c, fmi2DoStep(c, t, h, nosetprior));
    dosteps++;
    if (!c) return;
    if (st == fmi2OK) {
        double t1 = t + h, last;
        if (!(t1 > t)) finding("(d) DoStep returned OK although t + h == t (t %.17g, h %.17g)", t, h);
        last = real_status(s, &ok);
        if (!ok) finding("(d) fmi2GetRealStatus(fmi2LastSuccessfulTime) failed after an OK DoStep");
        else if (!isfinite(last)) finding("(c) fmi2LastSuccessfulTime = %g", last);
        else if (last != t1)
            finding("(d) DoStep(%.17g, %.17g) returned OK but fmi2LastSuccessfulTime = %.17g, not t + h = %.17g", t,
                    h, last, t1);
        long steps1 = 0;
        if (have_steps && read_steps(s, &steps1) == 0 && steps1 < steps0 + 1)
            finding("(d) DoStep(%.17g, %.17g) returned OK but solver.steps went %ld -> %ld (nothing integrated)", t,
                    h, steps0, steps1);
        check_outputs(s);
        total_steps_ok++;
        s->t = t1;
        s->t_known = 1;
        s->phase = P_STEP;
    } else if (st == fmi2Discard) {
        s->phase = P_FAILED;
    }
}

static void c_status(slot *s, int wild) {
    static const int KINDS[] = {fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated, 4, 99, -1};
    /* the kind each function answers: DoStepStatus, LastSuccessfulTime, (none), Terminated, PendingStatus */
    static const int NATURAL[] = {fmi2DoStepStatus, fmi2LastSuccessfulTime, fmi2Terminated, fmi2Terminated,
                                  fmi2PendingStatus};
    int which = irand(5);
    fmi2StatusKind kind = (fmi2StatusKind)(wild && chance(0.5) ? KINDS[irand(7)] : NATURAL[which]);
    int null_val = wild && chance(0.05);
    fmi2Component c = comp_of(s, wild);
    static const char *FN[] = {"fmi2GetStatus", "fmi2GetRealStatus", "fmi2GetIntegerStatus", "fmi2GetBooleanStatus",
                               "fmi2GetStringStatus"};
    begin(s, "%s(kind %d%s)", FN[which], (int)kind, null_val ? ", value NULL" : "");
    fmi2Status st;
    switch (which) {
        case 0: {
            fmi2Status *v = (fmi2Status *)malloc(sizeof *v);
            st = end(s, c, fmi2GetStatus(c, kind, null_val ? NULL : v));
            if (st == fmi2OK && !null_val && ((int)*v < 0 || (int)*v > 5))
                finding("(b) fmi2GetStatus value %d", (int)*v);
            free(v);
            break;
        }
        case 1: {
            fmi2Real *v = (fmi2Real *)malloc(sizeof *v);
            st = end(s, c, fmi2GetRealStatus(c, kind, null_val ? NULL : v));
            if (st == fmi2OK && !null_val && !isfinite(*v)) finding("(c) fmi2GetRealStatus value %g", *v);
            free(v);
            break;
        }
        case 2: {
            fmi2Integer *v = (fmi2Integer *)malloc(sizeof *v);
            end(s, c, fmi2GetIntegerStatus(c, kind, null_val ? NULL : v));
            free(v);
            break;
        }
        case 3: {
            fmi2Boolean *v = (fmi2Boolean *)malloc(sizeof *v);
            end(s, c, fmi2GetBooleanStatus(c, kind, null_val ? NULL : v));
            free(v);
            break;
        }
        default: {
            fmi2String *v = (fmi2String *)malloc(sizeof *v);
            st = end(s, c, fmi2GetStringStatus(c, kind, null_val ? NULL : v));
            if (st == fmi2OK && !null_val && !*v) finding("(c) fmi2GetStringStatus returned OK with NULL");
            free(v);
            break;
        }
    }
}

static void c_debug(slot *s, int wild) {
    static const char *GOOD[] = {"logEvents", "logStatusWarning", "logStatusDiscard", "logStatusError",
                                 "logStatusFatal", "logAll"};
    fmi2String cats[4];
    size_t n = (size_t)irand(4);
    int null_arr = wild && n > 0 && chance(0.1);
    char what[128] = "";
    for (size_t k = 0; k < n; k++) {
        int r = irand(10);
        cats[k] = wild && r == 0 ? NULL : wild && r == 1 ? "logNothing" : wild && r == 2 ? "%s%s%n" : GOOD[irand(6)];
        strncat(what, cats[k] ? cats[k] : "NULL", sizeof what - strlen(what) - 2);
        strncat(what, " ", sizeof what - strlen(what) - 1);
    }
    fmi2Boolean on = chance(0.5);
    fmi2Component c = comp_of(s, wild);
    begin(s, "fmi2SetDebugLogging(on %d, n %zu%s: %s)", on, n, null_arr ? ", categories NULL" : "", what);
    end(s, c, fmi2SetDebugLogging(c, on, n, null_arr ? NULL : cats));
}

static void c_unsupported(slot *s, int wild) {
    fmi2ValueReference vr[2] = {0, 1};
    fmi2Real dv[2] = {1.0, 2.0}, out[2];
    fmi2Integer order[2] = {1, 1};
    int which = irand(3), nulls = wild && chance(0.3);
    fmi2Component c = comp_of(s, wild);
    fmi2Status st;
    switch (which) {
        case 0:
            begin(s, "fmi2GetDirectionalDerivative(%s)", nulls ? "NULL arrays" : "2 x 2");
            st = fmi2GetDirectionalDerivative(c, nulls ? NULL : vr, 2, nulls ? NULL : vr, 2, nulls ? NULL : dv,
                                              nulls ? NULL : out);
            break;
        case 1:
            begin(s, "fmi2SetRealInputDerivatives(%s)", nulls ? "NULL arrays" : "n 2");
            st = fmi2SetRealInputDerivatives(c, nulls ? NULL : vr, 2, nulls ? NULL : order, nulls ? NULL : dv);
            break;
        default:
            begin(s, "fmi2GetRealOutputDerivatives(%s)", nulls ? "NULL arrays" : "n 2");
            st = fmi2GetRealOutputDerivatives(c, nulls ? NULL : vr, 2, nulls ? NULL : order, nulls ? NULL : out);
            break;
    }
    end(s, c, st);
}

static void c_version(slot *s) {
    begin(s, "fmi2GetTypesPlatform(), fmi2GetVersion()");
    const char *tp = fmi2GetTypesPlatform(), *ver = fmi2GetVersion();
    end(s, NULL, fmi2OK);
    if (!tp || strcmp(tp, "default") != 0) finding("fmi2GetTypesPlatform returned %s", tp ? tp : "NULL");
    if (!ver || strcmp(ver, "2.0") != 0) finding("fmi2GetVersion returned %s", ver ? ver : "NULL");
}

/* ------------------------------------------------------------------------------------------ FMU states */

static void c_get_state(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    if (wild && chance(0.05)) {
        begin(s, "fmi2GetFMUstate(FMUstate NULL)");
        end(s, c, fmi2GetFMUstate(c, NULL));
        return;
    }
    int reuse = npool > 0 && (npool == POOL || chance(0.4));
    int i = reuse ? irand(npool) : npool;
    fmi2FMUstate h = reuse ? pool[i].h : NULL;
    if (!reuse && wild && chance(0.1)) cur_fail_alloc = -1;
    begin(s, "fmi2GetFMUstate(%s %d%s)", reuse ? "into pool" : "new", i, cur_fail_alloc ? ", allocation fails" : "");
    cur_fail_alloc = 0;
    fmi2Status st = end(s, c, fmi2GetFMUstate(c, &h));
    if (st == fmi2OK && c) {
        if (!h) {
            finding("fmi2GetFMUstate returned OK with a NULL state");
            return;
        }
        pool[i].h = h;
        pool[i].phase = s->phase;
        pool[i].t = s->t;
        pool[i].t_known = s->t_known;
        if (!reuse) npool++;
    } else if (reuse) {
        pool[i].h = h;   /* an error may not free it: the handle stays the importer's to free */
    }
}

static void c_set_state(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    if (npool == 0 || (wild && chance(0.05))) {
        begin(s, "fmi2SetFMUstate(NULL)");
        end(s, c, fmi2SetFMUstate(c, NULL));
        return;
    }
    int i = irand(npool);
    begin(s, "fmi2SetFMUstate(pool %d)", i);
    fmi2Status st = end(s, c, fmi2SetFMUstate(c, pool[i].h));
    if (st == fmi2OK && c) {
        s->phase = pool[i].phase;
        s->t = pool[i].t;
        s->t_known = pool[i].t_known;
    }
}

static void c_free_state(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    if (npool == 0 || (wild && chance(0.1))) {
        int null_ptr = chance(0.5);
        fmi2FMUstate none = NULL;
        begin(s, "fmi2FreeFMUstate(%s)", null_ptr ? "NULL" : "pointer to NULL");
        end(s, c, fmi2FreeFMUstate(c, null_ptr ? NULL : &none));
        return;
    }
    int i = irand(npool);
    begin(s, "fmi2FreeFMUstate(pool %d)", i);
    fmi2Status st = end(s, c, fmi2FreeFMUstate(c, &pool[i].h));
    if (st == fmi2OK && c) {
        if (pool[i].h) finding("fmi2FreeFMUstate returned OK but did not set the handle to NULL");
        pool[i] = pool[--npool];
    }
}

static void c_state_size(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    size_t *sz = (size_t *)malloc(sizeof *sz);
    int null_state = npool == 0 || (wild && chance(0.1)), null_size = wild && chance(0.1);
    begin(s, "fmi2SerializedFMUstateSize(%s%s)", null_state ? "NULL state" : "pool", null_size ? ", size NULL" : "");
    fmi2Status st = end(s, c, fmi2SerializedFMUstateSize(c, null_state ? NULL : pool[irand(npool)].h,
                                                         null_size ? NULL : sz));
    if (st == fmi2OK && c && !null_size) state_size = *sz;
    free(sz);
}

static void c_serialize(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    if (npool == 0 || state_size == 0) {
        begin(s, "fmi2SerializeFMUstate(NULL state)");
        unsigned char b[8];
        end(s, c, fmi2SerializeFMUstate(c, NULL, (fmi2Byte *)b, sizeof b));
        return;
    }
    int i = irand(npool);
    size_t n = state_size;
    if (wild && chance(0.2)) n = chance(0.5) ? n - 1 - (size_t)irand(8) : n + 1 + (size_t)irand(8);
    unsigned char *b = (unsigned char *)malloc(n);   /* exactly n: a write past it is an ASan report */
    int null_buf = wild && chance(0.05);
    begin(s, "fmi2SerializeFMUstate(pool %d, size %zu of %zu%s)", i, n, state_size, null_buf ? ", buffer NULL" : "");
    fmi2Status st = end(s, c, fmi2SerializeFMUstate(c, pool[i].h, null_buf ? NULL : (fmi2Byte *)b, n));
    if (st == fmi2OK && c && !null_buf) {
        int j;
        if (nbufs < BUFS) {
            j = nbufs++;
        } else {
            j = irand(BUFS);
            free(bufs[j].b);
        }
        bufs[j].b = b;
        bufs[j].n = n;
        bufs[j].phase = pool[i].phase;
        bufs[j].t = pool[i].t;
        return;
    }
    free(b);
}

static void c_deserialize(slot *s, int wild) {
    fmi2Component c = comp_of(s, wild);
    if (nbufs == 0) {
        fmi2FMUstate h = NULL;
        begin(s, "fmi2DeSerializeFMUstate(NULL bytes)");
        end(s, c, fmi2DeSerializeFMUstate(c, NULL, 16, &h));
        return;
    }
    sbuf *src = &bufs[irand(nbufs)];
    size_t n = src->n;
    int corrupt = wild ? irand(6) : 0;   /* 0 intact, 1 flipped bytes, 2 truncated, 3 longer, 4 random body, 5 random */
    if (corrupt == 2) n = n > 1 ? n - 1 - (size_t)irand((int)(n < 64 ? n - 1 : 64)) : n;
    if (corrupt == 3) n = n + 1 + (size_t)irand(64);
    unsigned char *b = (unsigned char *)malloc(n);
    memcpy(b, src->b, n < src->n ? n : src->n);
    if (n > src->n) memset(b + src->n, 0xA5, n - src->n);
    char how[64] = "intact";
    if (corrupt == 1) {
        int flips = 1 + irand(4);
        for (int k = 0; k < flips; k++) b[irand((int)n)] ^= (unsigned char)(1 + irand(255));
        snprintf(how, sizeof how, "%d flipped bytes", flips);
    } else if (corrupt == 2 || corrupt == 3) {
        snprintf(how, sizeof how, "size %zu of %zu", n, src->n);
    } else if (corrupt == 4) {
        for (size_t k = 80; k < n; k++) b[k] = (unsigned char)rnd();   /* keeps magic, size, GUID, phase */
        snprintf(how, sizeof how, "random body after byte 80");
    } else if (corrupt == 5) {
        for (size_t k = 0; k < n; k++) b[k] = (unsigned char)rnd();
        snprintf(how, sizeof how, "random bytes");
    }
    int into = npool > 0 && (npool == POOL || chance(0.4));
    int i = into ? irand(npool) : npool;
    fmi2FMUstate h = into ? pool[i].h : NULL;
    if (!into && wild && chance(0.05)) cur_fail_alloc = -1;
    int null_out = wild && chance(0.04);
    begin(s, "fmi2DeSerializeFMUstate(%s, %s %d%s%s)", how, into ? "into pool" : "new", i,
          null_out ? ", FMUstate NULL" : "", cur_fail_alloc ? ", allocation fails" : "");
    cur_fail_alloc = 0;
    fmi2Status st = end(s, c, fmi2DeSerializeFMUstate(c, (const fmi2Byte *)b, n, null_out ? NULL : &h));
    free(b);
    if (st == fmi2OK && c && !null_out) {
        if (!h) {
            finding("fmi2DeSerializeFMUstate returned OK with a NULL state");
            return;
        }
        pool[i].h = h;
        pool[i].phase = corrupt ? P_UNKNOWN : src->phase;
        pool[i].t = src->t;
        pool[i].t_known = !corrupt;
        if (!into) npool++;
    } else if (into) {
        pool[i].h = h;
    }
}

/* ------------------------------------------------------------------------------------------- sequences */

enum kind {
    K_INST, K_FREE, K_SETUP, K_ENTER, K_EXIT, K_TERM, K_RESET, K_CANCEL, K_SETR, K_SETI, K_SETB, K_SETS, K_GETR,
    K_GETI, K_GETB, K_GETS, K_DOSTEP, K_STATUS, K_DEBUG, K_UNSUP, K_VERSION, K_GETSTATE, K_SETSTATE, K_FREESTATE,
    K_SSIZE, K_SER, K_DESER, N_KINDS
};

/* a call that makes sense in the phase the fuzzer believes the instance is in */
static enum kind natural(const slot *s) {
    int r = irand(100);
    switch (s->phase) {
        case P_NONE: return K_INST;
        case P_INST:
            return r < 25 ? K_SETUP : r < 45 ? K_SETR : r < 49 ? K_SETB : r < 55 ? K_SETI : r < 58 ? K_DEBUG : K_ENTER;
        case P_INIT: return r < 35 ? K_SETR : r < 40 ? K_SETB : r < 44 ? K_SETI : r < 55 ? K_GETR : K_EXIT;
        case P_STEP:
            return r < 45 ? K_DOSTEP : r < 62 ? K_SETR : r < 72 ? K_GETR : r < 75 ? K_GETI : r < 80 ? K_GETSTATE
                 : r < 84 ? K_SETSTATE : r < 88 ? K_SER : r < 92 ? K_DESER : r < 94 ? K_TERM : r < 97 ? K_STATUS
                 : K_FREESTATE;
        case P_FAILED: return r < 30 ? K_SETSTATE : r < 55 ? K_STATUS : r < 75 ? K_RESET : r < 85 ? K_TERM : K_GETR;
        case P_TERM: return r < 40 ? K_RESET : r < 65 ? K_FREE : r < 90 ? K_GETR : K_STATUS;
        default: return (enum kind)irand(N_KINDS);
    }
}

static void do_call(slot *s, enum kind k, int wild) {
    if (!s->c && k != K_INST && k != K_VERSION && !(wild && chance(0.3))) k = K_INST;
    if (k == K_DOSTEP && dosteps >= MAX_DOSTEPS) k = K_GETR;
    switch (k) {
        case K_INST: c_instantiate(s, wild); break;
        case K_FREE: c_free(s, wild); break;
        case K_SETUP: c_setup(s, wild); break;
        case K_ENTER: c_simple(s, wild, 0); break;
        case K_EXIT: c_simple(s, wild, 1); break;
        case K_TERM: c_simple(s, wild, 2); break;
        case K_RESET: c_simple(s, wild, 3); break;
        case K_CANCEL: c_simple(s, wild, 4); break;
        case K_SETR: c_set(s, wild, CEDRA_REAL); break;
        case K_SETI: c_set(s, wild, CEDRA_INTEGER); break;
        case K_SETB: c_set(s, wild, CEDRA_BOOLEAN); break;
        case K_SETS: c_set(s, wild, 3); break;
        case K_GETR: c_get(s, wild, CEDRA_REAL); break;
        case K_GETI: c_get(s, wild, CEDRA_INTEGER); break;
        case K_GETB: c_get(s, wild, CEDRA_BOOLEAN); break;
        case K_GETS: c_get(s, wild, 3); break;
        case K_DOSTEP: c_dostep(s, wild); break;
        case K_STATUS: c_status(s, wild); break;
        case K_DEBUG: c_debug(s, wild); break;
        case K_UNSUP: c_unsupported(s, wild); break;
        case K_VERSION: c_version(s); break;
        case K_GETSTATE: c_get_state(s, wild); break;
        case K_SETSTATE: c_set_state(s, wild); break;
        case K_FREESTATE: c_free_state(s, wild); break;
        case K_SSIZE: c_state_size(s, wild); break;
        case K_SER: c_serialize(s, wild); break;
        case K_DESER: c_deserialize(s, wild); break;
        default: break;
    }
}

static void run_sequence(unsigned long long seed) {
    uint64_t x = seed;
    rng = splitmix64(&x);
    cur_seed = seed;
    call_idx = 0;
    seq_failed = 0;
    dosteps = 0;
    npool = nbufs = 0;
    nslots = 1 + irand(MAX_INST);
    for (int i = 0; i < nslots; i++) {
        memset(&slots[i], 0, sizeof slots[i]);
        slots[i].id = i;
    }
    int len = 10 + irand(70);
    double p_wild = 0.1 + 0.4 * urand();   /* some sequences mostly valid (they get deep), some mostly wild */
    if (opt.trace) printf("sequence seed=%llu: %d instances, %d calls, p_wild %.2f\n", seed, nslots, len, p_wild);
    in_sequence = 1;
    for (int k = 0; k < len && !seq_failed; k++) {
        slot *s = &slots[irand(nslots)];
        int wild = chance(p_wild);
        do_call(s, wild ? (enum kind)irand(N_KINDS) : natural(s), wild);
    }
    /* cleanup, checked like any call */
    slot *any = live_slot();
    if (any && npool) free_pool_via(any);
    for (int i = 0; i < npool; i++) free(pool[i].h);   /* no live instance left to free them: the fuzzer's calloc */
    npool = 0;
    for (int i = 0; i < nslots; i++) free_slot(&slots[i]);
    for (int i = 0; i < nbufs; i++) free(bufs[i].b);
    nbufs = 0;
    free(snap_before);
    snap_before = NULL;
    cur = NULL;
    in_sequence = 0;
}

static int fuzz_main(void) {
    double t0 = now();
    long done = 0;
    for (long k = 0; k < opt.sequences; k++) {
        if (opt.seconds > 0 && now() - t0 > opt.seconds) break;
        printf("SEQ %llu calls=%ld dosteps_ok=%ld\n", opt.seed + (unsigned long long)k, total_calls, total_steps_ok);
        fflush(stdout);
        run_sequence(opt.seed + (unsigned long long)k);
        done++;
        if (total_findings && !opt.keep_going) break;
    }
    printf("DONE sequences=%ld calls=%ld checks=%ld findings=%ld seconds=%.2f dosteps_ok=%ld\n", done, total_calls,
           total_checks, total_findings, now() - t0, total_steps_ok);
    return total_findings ? 1 : 0;
}

/* --------------------------------------------------------------------------------------- leak cycles */

static void quiet_logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                         fmi2String message, ...) {
    char text[2048];
    va_list ap;
    (void)env, (void)name, (void)category;
    va_start(ap, message);
    vsnprintf(text, sizeof text, message, ap);
    va_end(ap);
    if (opt.trace || status >= fmi2Discard) fprintf(stderr, "  [%s] %s\n", status_name((int)status), text);
}

static fmi2Component instantiate_plain(const char *name, const char *res, const fmi2CallbackFunctions *cb) {
    return fmi2Instantiate(name, fmi2CoSimulation, CEDRA_GUID, res, cb, fmi2False, fmi2False);
}

#define MUST(call)                                                                                                \
    do {                                                                                                          \
        fmi2Status st_ = (call);                                                                                  \
        if (st_ != fmi2OK) {                                                                                      \
            printf("FAILED cycle %ld: %s returned %s\n", k, #call, status_name((int)st_));                        \
            return 1;                                                                                             \
        }                                                                                                         \
    } while (0)

static int set_torques(fmi2Component c, double base) {
    for (int i = 1; i <= 6; i++) {
        char nm[32];
        snprintf(nm, sizeof nm, "tau[%d]", i);
        const cedra_var *v = var_named(nm);
        if (!v) continue;
        fmi2ValueReference vr = v->vr;
        fmi2Real val = base * (1.0 + 0.05 * i);
        if (fmi2SetReal(c, &vr, 1, &val) != fmi2OK) return 1;
    }
    return 0;
}

/* The leak and thread runs check memory and results, not speed: under valgrind a step is ~50 times slower and the
 * product's default wall-clock budget per fmi2DoStep (solver.max_wall_time, 1 s) would discard it; these runs
 * lift it to its maximum (the attempted-step budget still bounds every call). 0, or 1 if it cannot be set. */
static int lift_wall_budget(fmi2Component c) {
    const cedra_var *v = var_named("solver.max_wall_time");
    if (!v) return 0;                                      /* the controller has no solver */
    fmi2ValueReference vr = v->vr;
    fmi2Real val = v->max;
    return fmi2SetReal(c, &vr, 1, &val) != fmi2OK;
}

static int cycles_main(void) {
    fmi2CallbackFunctions cb = {quiet_logger, fuzz_calloc, free, NULL, NULL};
    const char *res = opt.nres ? opt.res[0] : NULL;
    for (long k = 0; k < opt.cycles; k++) {
        /* the failure paths of fmi2Instantiate: each of its first allocations failing in turn, and a refusal */
        fail_at = 1 + (int)(k % 6);
        alloc_count = alloc_failed = 0;
        fmi2Component bad = instantiate_plain("oom", res, &cb);
        fail_at = 0;
        if (bad) fmi2FreeInstance(bad);
        bad = fmi2Instantiate("guid", fmi2CoSimulation, "{wrong}", res, &cb, fmi2False, fmi2False);
        if (bad) {
            printf("FAILED cycle %ld: a wrong GUID was accepted\n", k);
            return 1;
        }
        fmi2Component c = instantiate_plain("leak", res, &cb);
        if (!c) {
            printf("FAILED cycle %ld: fmi2Instantiate returned NULL\n", k);
            return 1;
        }
        int stop_at = 4 - (int)(k % 5);   /* free the instance in different phases, the full cycle first */
        MUST(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
        if (lift_wall_budget(c)) {
            printf("FAILED cycle %ld: setting solver.max_wall_time\n", k);
            return 1;
        }
        if (stop_at == 0) goto done;
        MUST(fmi2EnterInitializationMode(c));
        if (set_torques(c, 0.5 + 0.1 * (double)(k % 3))) {
            printf("FAILED cycle %ld: setting the torques\n", k);
            return 1;
        }
        if (stop_at == 1) goto done;
        MUST(fmi2ExitInitializationMode(c));
        double t = 0.0;
        for (int i = 0; i < 3; i++, t += 0.01) MUST(fmi2DoStep(c, t, 0.01, fmi2True));
        fmi2FMUstate st = NULL, st2 = NULL;
        size_t n = 0;
        MUST(fmi2GetFMUstate(c, &st));
        MUST(fmi2GetFMUstate(c, &st));   /* overwrite in place */
        MUST(fmi2SerializedFMUstateSize(c, st, &n));
        fmi2Byte *buf = (fmi2Byte *)malloc(n);
        MUST(fmi2SerializeFMUstate(c, st, buf, n));
        MUST(fmi2DeSerializeFMUstate(c, buf, n, &st2));
        MUST(fmi2DeSerializeFMUstate(c, buf, n, &st2));   /* into an existing state */
        /* the out-of-memory paths of the state functions */
        fmi2FMUstate none = NULL;
        fail_at = -1;
        fmi2GetFMUstate(c, &none);
        fmi2DeSerializeFMUstate(c, buf, n, &none);
        fail_at = 0;
        free(buf);
        if (none) fmi2FreeFMUstate(c, &none);
        MUST(fmi2DoStep(c, t, 0.01, fmi2True));
        MUST(fmi2SetFMUstate(c, st2));
        MUST(fmi2DoStep(c, t, 0.01, fmi2True));
        MUST(fmi2FreeFMUstate(c, &st));
#ifndef FUZZ_PLANT_LEAK
        MUST(fmi2FreeFMUstate(c, &st2));
#endif
        if (stop_at == 2) goto done;
        MUST(fmi2Terminate(c));
        if (stop_at == 3) goto done;
        MUST(fmi2Reset(c));
    done:
        fmi2FreeInstance(c);
    }
    printf("CYCLES done n=%ld\n", opt.cycles);
    return 0;
}

/* ------------------------------------------------------------------------------------------ threads */

typedef struct {
    int id;
    const char *res;
    double *out;         /* steps x n_out */
    unsigned char *end;  /* serialized end state */
    size_t end_n;
    int failed;
    char why[256];
    pthread_barrier_t *barrier;
} scenario;

static size_t n_real_outputs(fmi2ValueReference *vr) {
    size_t n = 0;
    for (int i = 0; i < CEDRA_NVARS; i++)
        if (CEDRA_VARS[i].causality == CEDRA_OUTPUT && CEDRA_VARS[i].type == CEDRA_REAL) {
            if (vr) vr[n] = CEDRA_VARS[i].vr;
            n++;
        }
    return n;
}

static void *run_scenario(void *arg) {
    scenario *sc = (scenario *)arg;
    fmi2CallbackFunctions cb = {quiet_logger, calloc, free, NULL, NULL};   /* no injected failures: shared state */
    fmi2ValueReference vr[CEDRA_NVARS];
    size_t n = n_real_outputs(vr);
    char name[32];
    snprintf(name, sizeof name, "thread%d", sc->id);
    if (sc->barrier) pthread_barrier_wait(sc->barrier);   /* all threads step at the same time */
    fmi2Component c = instantiate_plain(name, sc->res, &cb);
    if (!c) {
        snprintf(sc->why, sizeof sc->why, "fmi2Instantiate failed");
        sc->failed = 1;
        return NULL;
    }
    fmi2FMUstate st = NULL;
    double t = 0.0;
    if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK || lift_wall_budget(c) ||
        fmi2EnterInitializationMode(c) != fmi2OK || set_torques(c, 0.4 + 0.35 * sc->id) ||
        fmi2ExitInitializationMode(c) != fmi2OK) {
        snprintf(sc->why, sizeof sc->why, "initialization failed");
        sc->failed = 1;
        goto out;
    }
    for (int k = 0; k < opt.steps; k++, t += 0.01) {
        fmi2Status s = fmi2DoStep(c, t, 0.01, fmi2True);
        if (s != fmi2OK || fmi2GetReal(c, vr, n, sc->out + (size_t)k * n) != fmi2OK) {
            snprintf(sc->why, sizeof sc->why, "step %d at t=%g: %s", k, t, status_name((int)s));
            sc->failed = 1;
            goto out;
        }
    }
    if (fmi2GetFMUstate(c, &st) != fmi2OK || fmi2SerializedFMUstateSize(c, st, &sc->end_n) != fmi2OK) {
        sc->failed = 1;
        goto out;
    }
    sc->end = (unsigned char *)malloc(sc->end_n);
    if (fmi2SerializeFMUstate(c, st, (fmi2Byte *)sc->end, sc->end_n) != fmi2OK) sc->failed = 1;
    fmi2FreeFMUstate(c, &st);
out:
    fmi2FreeInstance(c);
    return NULL;
}

static int threads_main(void) {
    int N = opt.threads;
    size_t n = n_real_outputs(NULL);
    scenario *seq = (scenario *)calloc((size_t)N, sizeof *seq), *par = (scenario *)calloc((size_t)N, sizeof *par);
    pthread_t *th = (pthread_t *)calloc((size_t)N, sizeof *th);
    pthread_barrier_t barrier;
    pthread_barrier_init(&barrier, NULL, (unsigned)N);
    int bad = 0;
    for (int i = 0; i < N; i++) {
        for (int pass = 0; pass < 2; pass++) {
            scenario *sc = pass ? &par[i] : &seq[i];
            sc->id = i;
            sc->res = opt.nres ? opt.res[i % opt.nres] : NULL;
            sc->out = (double *)calloc((size_t)opt.steps * n, sizeof(double));
            sc->barrier = pass ? &barrier : NULL;
        }
    }
    double t0 = now();
    for (int i = 0; i < N; i++) run_scenario(&seq[i]);
    double t1 = now();
    for (int i = 0; i < N; i++) pthread_create(&th[i], NULL, run_scenario, &par[i]);
    for (int i = 0; i < N; i++) pthread_join(th[i], NULL);
    double t2 = now();
    fmi2ValueReference vr[CEDRA_NVARS];
    n_real_outputs(vr);
    for (int i = 0; i < N; i++) {
        if (seq[i].failed || par[i].failed) {
            printf("FINDING threads: scenario %d failed: %s%s\n", i, seq[i].why, par[i].why);
            bad = 1;
            continue;
        }
        for (int k = 0; k < opt.steps && !bad; k++)
            for (size_t j = 0; j < n; j++)
                if (memcmp(&seq[i].out[(size_t)k * n + j], &par[i].out[(size_t)k * n + j], sizeof(double)) != 0) {
                    printf("FINDING threads: scenario %d, step %d, %s: %.17g one after another, %.17g in threads\n", i,
                           k, var_by_vr(vr[j])->name, seq[i].out[(size_t)k * n + j], par[i].out[(size_t)k * n + j]);
                    bad = 1;
                    break;
                }
        if (seq[i].end_n != par[i].end_n || memcmp(seq[i].end, par[i].end, seq[i].end_n) != 0) {
            printf("FINDING threads: scenario %d: the serialized end states differ\n", i);
            bad = 1;
        }
        if (i > 0 && memcmp(seq[i].out, seq[0].out, (size_t)opt.steps * n * sizeof(double)) == 0) {
            printf("FINDING threads: scenarios 0 and %d give the same outputs: mixing would not show\n", i);
            bad = 1;
        }
    }
    printf("THREADS n=%d steps=%d outputs=%zu state_bytes=%zu sequential=%.2fs threads=%.2fs %s\n", N, opt.steps, n,
           seq[0].end_n, t1 - t0, t2 - t1, bad ? "DIFFERENT" : "identical");
    for (int i = 0; i < N; i++) free(seq[i].out), free(par[i].out), free(seq[i].end), free(par[i].end);
    free(seq), free(par), free(th);
    pthread_barrier_destroy(&barrier);
    return bad;
}

/* ------------------------------------------------------------------------------------------------ main */

static void usage(void) {
    fprintf(stderr, "usage: fmu_fuzz [--seed S] [--sequences N] [--seconds T] [--call-limit T] [--keep-going] "
                    "[--trace] [--resources URI]... | --cycles N | --threads N [--steps M]\n");
    exit(2);
}

int main(int argc, char **argv) {
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--keep-going")) opt.keep_going = 1;
        else if (!strcmp(a, "--trace")) opt.trace = 1;
        else if (!v) usage();
        else if (!strcmp(a, "--seed")) opt.seed = strtoull(v, NULL, 10), i++;
        else if (!strcmp(a, "--sequences")) opt.sequences = strtol(v, NULL, 10), i++;
        else if (!strcmp(a, "--seconds")) opt.seconds = strtod(v, NULL), i++;
        else if (!strcmp(a, "--call-limit")) opt.call_limit = strtod(v, NULL), i++;
        else if (!strcmp(a, "--cycles")) opt.cycles = strtol(v, NULL, 10), i++;
        else if (!strcmp(a, "--threads")) opt.threads = (int)strtol(v, NULL, 10), i++;
        else if (!strcmp(a, "--steps")) opt.steps = (int)strtol(v, NULL, 10), i++;
        else if (!strcmp(a, "--resources") && opt.nres < MAX_RES) opt.res[opt.nres++] = v, i++;
        else usage();
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (opt.cycles > 0) return cycles_main();
    if (opt.threads > 0) return threads_main();
    signal(SIGALRM, on_alarm);
#if defined(__SANITIZE_ADDRESS__)
    __sanitizer_set_death_callback(on_sanitizer_death);
#endif
    return fuzz_main();
}
