/* FMI 2.0 Co-Simulation interface of a cedra FMU (hand-written, the same for every FMU): the generic part.
 *
 * Reference-FMUs style: the instance holds one plain struct `cedra_state` (time, inputs, parameters, outputs,
 * status flags, phase, and the block's own state: glue.h), so fmi2GetFMUstate/SetFMUstate are struct copies
 * and serialization is a memcpy with a checksum and a check of every field. Scratch memory lives outside the
 * state. What happens between communication points is the block's (plant.c: an integrated model; controller.c:
 * a sampled controller).
 *
 * Logging: messages with a status other than fmi2OK (warnings, discards, errors) are always sent to the logger;
 * logEvents messages (initialization, settle) only when debug logging is on for logEvents or logAll.
 * Errors caused by a bad argument or call order leave the instance as it was (the call has no effect): a call
 * checks everything it was given before it writes anything. fmi2DoStep returns fmi2OK only after the block did
 * the whole communication step, within the block's bound on its cost.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "glue.h"

#define STATE_MAGIC 0xCED2A0F3u
#define MAX_START_TIME 1e9          /* s, see fmi2SetupExperiment */

#define PH_ANY (PH_INSTANTIATED | PH_INIT | PH_STEP_COMPLETE | PH_STEP_FAILED | PH_TERMINATED)
#define PH_GET (PH_INIT | PH_STEP_COMPLETE | PH_STEP_FAILED | PH_TERMINATED)
#define PH_SET (PH_INSTANTIATED | PH_INIT | PH_STEP_COMPLETE)

static const char *const CAT_NAMES[N_CATS] = {"logEvents", "logStatusWarning", "logStatusDiscard",
                                               "logStatusError", "logStatusFatal", "logAll"};

double time_resolution(double t) { return 1e-12 * fmax(1.0, fabs(t)); }

/* ------------------------------------------------------------------------------------------------ logging */

void log_msg(instance *c, fmi2Status status, int cat, const char *fmt, ...) {
    char text[2 * MSG_LEN], esc[4 * MSG_LEN];
    va_list ap;
    if (!c || !c->logger) return;
    if (status == fmi2OK && !(c->log_on[cat] || c->log_on[CAT_ALL])) return;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    /* the logger takes a printf format: pass the finished text with '%' escaped */
    size_t k = 0;
    for (const char *p = text; *p && k + 2 < sizeof esc; p++) {
        if (*p == '%') esc[k++] = '%';
        esc[k++] = *p;
    }
    esc[k] = '\0';
    c->logger(c->env, c->name ? c->name : "", status, CAT_NAMES[cat], esc);
}

#define FAIL(c, ...) (log_msg((c), fmi2Error, CAT_ERROR, __VA_ARGS__), fmi2Error)

static const char *phase_name(int ph) {
    switch (ph) {
        case PH_INSTANTIATED: return "instantiated";
        case PH_INIT: return "initialization mode";
        case PH_STEP_COMPLETE: return "step complete";
        case PH_STEP_FAILED: return "step failed (terminated)";
        case PH_TERMINATED: return "terminated";
        default: return "unknown";
    }
}

/* 1 if the call is allowed in the current phase, else logs and returns 0 */
static int allowed(instance *c, const char *fn, int mask) {
    if (c->s.phase & mask) return 1;
    log_msg(c, fmi2Error, CAT_ERROR, "%s: not allowed in state %s", fn, phase_name(c->s.phase));
    return 0;
}

/* -------------------------------------------------------------------------------------------- state setup */

static void set_defaults(instance *c, double start_time) {
    cedra_state *s = &c->s;
    memset(s, 0, sizeof *s);
    s->magic = STATE_MAGIC;
    s->size = (unsigned int)sizeof *s;
    snprintf(s->guid, sizeof s->guid, "%s", CEDRA_GUID);
    s->phase = PH_INSTANTIATED;
    s->time = s->start_time = s->last_good_time = start_time;
    for (int i = 0; i < CEDRA_NP; i++) s->par[i] = CEDRA_PAR_START[i];
    for (int i = 0; i < CEDRA_NI; i++) s->inp[i] = CEDRA_INP_START[i];
    block_defaults(s);
}

/* ---------------------------------------------------------------------------------------- generic functions */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (nCategories > 0 && !categories) return FAIL(c, "fmi2SetDebugLogging: categories is NULL");
    for (size_t k = 0; k < nCategories; k++) {
        int found = 0;
        for (int j = 0; j < N_CATS && categories[k]; j++) found |= strcmp(categories[k], CAT_NAMES[j]) == 0;
        if (!found)
            return FAIL(c, "fmi2SetDebugLogging: unknown log category %s", categories[k] ? categories[k] : "(NULL)");
    }
    if (nCategories == 0) {
        for (int j = 0; j < N_CATS; j++) c->log_on[j] = loggingOn != fmi2False;
    } else {
        for (size_t k = 0; k < nCategories; k++)
            for (int j = 0; j < N_CATS; j++)
                if (strcmp(categories[k], CAT_NAMES[j]) == 0) c->log_on[j] = loggingOn != fmi2False;
    }
    return fmi2OK;
}

static void free_instance(instance *c) {
    block_free(c);
    if (c->name) c->free(c->name);
    c->free(c);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    (void)visible;
    if (!functions || !functions->logger) return NULL;
    instance tmp;                     /* for logging before the instance exists */
    memset(&tmp, 0, sizeof tmp);
    tmp.logger = functions->logger;
    tmp.env = functions->componentEnvironment;
    tmp.name = (char *)(instanceName ? instanceName : "");
    if (!functions->allocateMemory || !functions->freeMemory) {
        log_msg(&tmp, fmi2Error, CAT_ERROR, "fmi2Instantiate: allocateMemory and freeMemory are required");
        return NULL;
    }
    if (!instanceName || !instanceName[0]) {
        log_msg(&tmp, fmi2Error, CAT_ERROR, "fmi2Instantiate: instanceName is NULL or empty");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        log_msg(&tmp, fmi2Error, CAT_ERROR, "fmi2Instantiate: %s supports Co-Simulation only (fmuType %d)",
                CEDRA_MODEL_IDENTIFIER, (int)fmuType);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, CEDRA_GUID) != 0) {
        log_msg(&tmp, fmi2Error, CAT_ERROR, "fmi2Instantiate: GUID %s does not match the FMU's GUID %s",
                fmuGUID ? fmuGUID : "(NULL)", CEDRA_GUID);
        return NULL;
    }
    instance *c = (instance *)functions->allocateMemory(1, sizeof(instance));
    if (!c) {
        log_msg(&tmp, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        return NULL;
    }
    memset(c, 0, sizeof *c);
    c->logger = functions->logger;
    c->alloc = functions->allocateMemory;
    c->free = functions->freeMemory;
    c->env = functions->componentEnvironment;
    c->name = (char *)c->alloc(strlen(instanceName) + 1, 1);
    if (!c->name) {
        log_msg(&tmp, fmi2Fatal, CAT_FATAL, "fmi2Instantiate: out of memory");
        free_instance(c);
        return NULL;
    }
    strcpy(c->name, instanceName);
    for (int j = 0; j < N_CATS; j++) c->log_on[j] = loggingOn != fmi2False;
    if (block_instantiate(c, fmuResourceLocation)) {
        free_instance(c);
        return NULL;
    }
    set_defaults(c, 0.0);
    return (fmi2Component)c;
}

void fmi2FreeInstance(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (c) free_instance(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2SetupExperiment", PH_INSTANTIATED)) return fmi2Error;
    if (!isfinite(startTime)) return FAIL(c, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
    /* the FMU resolves time to 1e-12 |t| (time_resolution): beyond 1e9 s not even a 1 ms step could be
     * resolved, and at 1e300 a step would not advance time at all */
    if (fabs(startTime) > MAX_START_TIME)
        return FAIL(c, "fmi2SetupExperiment: startTime = %g is beyond +-%g s, where the FMU cannot resolve time "
                    "steps below %g s", startTime, MAX_START_TIME, time_resolution(MAX_START_TIME));
    if (stopTimeDefined && !(stopTime >= startTime))
        return FAIL(c, "fmi2SetupExperiment: stopTime = %g is before startTime = %g", stopTime, startTime);
    if (toleranceDefined && !(tolerance > 0 && isfinite(tolerance)))
        return FAIL(c, "fmi2SetupExperiment: tolerance = %g must be > 0 and finite", tolerance);
    if (toleranceDefined) block_tolerance(c, tolerance);
    c->s.time = c->s.start_time = c->s.last_good_time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2EnterInitializationMode", PH_INSTANTIATED)) return fmi2Error;
    c->s.phase = PH_INIT;
    c->s.outputs_valid = 0;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2ExitInitializationMode", PH_INIT)) return fmi2Error;
    if (block_initialize(c, "fmi2ExitInitializationMode")) return fmi2Error;
    c->s.phase = PH_STEP_COMPLETE;
    c->s.last_good_time = c->s.time;
    log_msg(c, fmi2OK, CAT_EVENTS, "fmi2ExitInitializationMode: initialized at t=%g", c->s.time);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2Terminate", PH_STEP_COMPLETE | PH_STEP_FAILED)) return fmi2Error;
    c->s.phase = PH_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2Reset", PH_ANY)) return fmi2Error;
    set_defaults(c, 0.0);
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------- variable access */

static const char *TYPE_NAMES[] = {"Real", "Integer", "Boolean"};

/* the variable with value reference vr and type `type`, or NULL (logged) */
static const cedra_var *lookup(instance *c, const char *fn, fmi2ValueReference vr, int type) {
    if (vr >= (fmi2ValueReference)CEDRA_NVARS) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: unknown value reference %u", fn, (unsigned)vr);
        return NULL;
    }
    const cedra_var *v = &CEDRA_VARS[vr];
    if (type >= 0 && v->type != type) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: variable %s (vr %u) is a%s %s", fn, v->name, (unsigned)vr,
                v->type == CEDRA_INTEGER ? "n" : "", TYPE_NAMES[v->type]);
        return NULL;
    }
    return v;
}

static int check_array_args(instance *c, const char *fn, const void *vr, size_t nvr, const void *value) {
    if (nvr > 0 && !vr) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: vr is NULL", fn);
        return 0;
    }
    if (nvr > 0 && !value) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: value is NULL", fn);
        return 0;
    }
    return 1;
}

/* value of a variable as a double (Integer/Boolean too); outputs in initialization mode are computed first */
static int get_value(instance *c, const char *fn, const cedra_var *v, double *out) {
    cedra_state *s = &c->s;
    switch (v->kind) {
        case CEDRA_K_PAR: *out = s->par[v->index]; return 0;
        case CEDRA_K_INP: *out = s->inp[v->index]; return 0;
        case CEDRA_K_OUT:
            if (s->phase == PH_INIT && block_outputs(c, fn)) return 1;
            *out = s->y[v->index];
            return 0;
        default: return block_value(s, v, out);
    }
}

/* stores a value as element k of an fmi2Get* array of the given type */
static void store_as(void *values, int type, size_t k, double d) {
    switch (type) {
        case CEDRA_REAL: ((fmi2Real *)values)[k] = d; break;
        case CEDRA_INTEGER:
            d = nearbyint(d);
            ((fmi2Integer *)values)[k] = d > 2147483647.0 ? 2147483647 : d < -2147483648.0 ? (-2147483647 - 1)
                                                                                          : (fmi2Integer)d;
            break;
        default: ((fmi2Boolean *)values)[k] = d != 0.0 ? fmi2True : fmi2False; break;
    }
}

/* Every reference is checked before any value is computed: an output read in initialization mode computes the
 * start state, which a refused call must not leave behind. */
static fmi2Status get_values(instance *c, const char *fn, const fmi2ValueReference vr[], size_t nvr, void *values,
                             int type) {
    for (size_t k = 0; k < nvr; k++)
        if (!lookup(c, fn, vr[k], type)) return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        double d;
        if (get_value(c, fn, &CEDRA_VARS[vr[k]], &d)) return fmi2Error;
        store_as(values, type, k, d);
    }
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetReal", PH_GET) || !check_array_args(c, "fmi2GetReal", vr, nvr, value)) return fmi2Error;
    return get_values(c, "fmi2GetReal", vr, nvr, value, CEDRA_REAL);
}

fmi2Status fmi2GetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetInteger", PH_GET) || !check_array_args(c, "fmi2GetInteger", vr, nvr, value))
        return fmi2Error;
    return get_values(c, "fmi2GetInteger", vr, nvr, value, CEDRA_INTEGER);
}

fmi2Status fmi2GetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetBoolean", PH_GET) || !check_array_args(c, "fmi2GetBoolean", vr, nvr, value))
        return fmi2Error;
    return get_values(c, "fmi2GetBoolean", vr, nvr, value, CEDRA_BOOLEAN);
}

fmi2Status fmi2GetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetString", PH_GET) || !check_array_args(c, "fmi2GetString", vr, nvr, value))
        return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        const cedra_var *v = lookup(c, "fmi2GetString", vr[k], -1);
        if (v) log_msg(c, fmi2Error, CAT_ERROR, "fmi2GetString: variable %s (vr %u) is not a String", v->name,
                       (unsigned)vr[k]);
        return fmi2Error;
    }
    return fmi2OK;
}

/* 0 if d is a valid value of v (finite, within min/max), else 1 with the reason ("= nan is not finite") in why */
static int check_range(const cedra_var *v, double d, char *why, size_t len) {
    if (!isfinite(d)) {
        snprintf(why, len, "= %g is not finite", d);
        return 1;
    }
    if (d < v->min || (v->min_exclusive && d == v->min)) {
        snprintf(why, len, "= %.17g must be %s %.17g", d, v->min_exclusive ? ">" : ">=", v->min);
        return 1;
    }
    if (d > v->max) {
        snprintf(why, len, "= %.17g must be <= %.17g", d, v->max);
        return 1;
    }
    return 0;
}

/* 0 if v may be set to d now, else 1 (logged); writes nothing */
static int check_set(instance *c, const char *fn, const cedra_var *v, double d) {
    char why[160];
    if (v->causality == CEDRA_OUTPUT) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: variable %s (vr %u) is an output (calculated), it cannot be set", fn,
                v->name, v->vr);
        return 1;
    }
    if (v->causality == CEDRA_PARAMETER && !(c->s.phase & (PH_INSTANTIATED | PH_INIT))) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: parameter %s (vr %u) is fixed: it can be set only before "
                "fmi2ExitInitializationMode", fn, v->name, v->vr);
        return 1;
    }
    if (check_range(v, d, why, sizeof why)) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: variable %s (vr %u) %s", fn, v->name, v->vr, why);
        return 1;
    }
    return 0;
}

/* stores a value check_set accepted */
static void store_value(instance *c, const cedra_var *v, double d) {
    cedra_state *s = &c->s;
    switch (v->kind) {
        case CEDRA_K_PAR: s->par[v->index] = d; break;
        case CEDRA_K_INP: s->inp[v->index] = d; break;
        default: block_store(s, v, d); break;
    }
    if (s->phase & (PH_INSTANTIATED | PH_INIT)) s->outputs_valid = 0;
}

/* value k of an fmi2Set* array of the given type, as a double */
static double value_as_double(const void *values, int type, size_t k) {
    switch (type) {
        case CEDRA_REAL: return ((const fmi2Real *)values)[k];
        case CEDRA_INTEGER: return (double)((const fmi2Integer *)values)[k];
        default: return ((const fmi2Boolean *)values)[k] ? 1.0 : 0.0;
    }
}

/* All or nothing: every (vr, value) pair is checked before the first one is stored, so a refused call leaves
 * the instance as it was. */
static fmi2Status set_values(instance *c, const char *fn, const fmi2ValueReference vr[], size_t nvr,
                             const void *values, int type) {
    for (size_t k = 0; k < nvr; k++) {
        const cedra_var *v = lookup(c, fn, vr[k], type);
        if (!v || check_set(c, fn, v, value_as_double(values, type, k))) return fmi2Error;
    }
    for (size_t k = 0; k < nvr; k++) store_value(c, &CEDRA_VARS[vr[k]], value_as_double(values, type, k));
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2SetReal", PH_SET) || !check_array_args(c, "fmi2SetReal", vr, nvr, value)) return fmi2Error;
    return set_values(c, "fmi2SetReal", vr, nvr, value, CEDRA_REAL);
}

fmi2Status fmi2SetInteger(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2SetInteger", PH_SET) || !check_array_args(c, "fmi2SetInteger", vr, nvr, value))
        return fmi2Error;
    return set_values(c, "fmi2SetInteger", vr, nvr, value, CEDRA_INTEGER);
}

fmi2Status fmi2SetBoolean(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2SetBoolean", PH_SET) || !check_array_args(c, "fmi2SetBoolean", vr, nvr, value))
        return fmi2Error;
    return set_values(c, "fmi2SetBoolean", vr, nvr, value, CEDRA_BOOLEAN);
}

fmi2Status fmi2SetString(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[]) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2SetString", PH_SET) || !check_array_args(c, "fmi2SetString", vr, nvr, value))
        return fmi2Error;
    for (size_t k = 0; k < nvr; k++) {
        const cedra_var *v = lookup(c, "fmi2SetString", vr[k], -1);
        if (v) log_msg(c, fmi2Error, CAT_ERROR, "fmi2SetString: variable %s (vr %u) is not a String", v->name,
                       (unsigned)vr[k]);
        return fmi2Error;
    }
    return fmi2OK;
}

/* ----------------------------------------------------------------------------------------------- FMU state */

/* 1 if st is a state of this FMU (magic, size, GUID), else 0 (logged) */
static int state_ok(instance *c, const char *fn, const cedra_state *st) {
    if (st->magic != STATE_MAGIC || st->size != sizeof(cedra_state) || memchr(st->guid, '\0', sizeof st->guid) == NULL
        || strcmp(st->guid, CEDRA_GUID) != 0) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: not a state of this FMU (%s)", fn, CEDRA_MODEL_IDENTIFIER);
        return 0;
    }
    return 1;
}

int all_finite(const double *v, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

static int is_flag(int v) { return v == 0 || v == 1; }

/* 1 if st is a state of this FMU whose every field is one the FMU could have made: a known phase, flags 0/1,
 * finite times and outputs, every variable the importer can set within its range, and a block state the block
 * accepts (plant: finite x, counters >= 0, a state the model can evaluate); else 0 (logged with the first
 * reason found) */
static int state_valid(instance *c, const char *fn, const cedra_state *st) {
    const char *why = NULL;
    char buf[200];
    if (!state_ok(c, fn, st)) return 0;
    if (st->phase != PH_INSTANTIATED && st->phase != PH_INIT && st->phase != PH_STEP_COMPLETE &&
        st->phase != PH_STEP_FAILED && st->phase != PH_TERMINATED)
        why = "its phase is not one of this FMU's";
    else if (!is_flag(st->terminated) || !is_flag(st->outputs_valid))
        why = "a flag is neither 0 nor 1";
    else if (!isfinite(st->time) || !isfinite(st->start_time) || !isfinite(st->last_good_time))
        why = "a time is not finite";
    else if (!all_finite(st->y, CEDRA_NY))
        why = "the state x or the outputs are not finite";
    for (int i = 0; !why && i < CEDRA_NVARS; i++) {
        const cedra_var *v = &CEDRA_VARS[i];
        double d;
        char range[160];
        if (v->causality == CEDRA_OUTPUT) continue;
        if (v->kind == CEDRA_K_PAR) d = st->par[v->index];
        else if (v->kind == CEDRA_K_INP) d = st->inp[v->index];
        else if (block_value(st, v, &d)) continue;
        if (check_range(v, d, range, sizeof range)) {
            snprintf(buf, sizeof buf, "its %s %s", v->name, range);
            why = buf;
        }
    }
    if (!why) why = block_state_problem(c, st, buf, sizeof buf);
    if (why) {
        log_msg(c, fmi2Error, CAT_ERROR, "%s: refused, %s", fn, why);
        return 0;
    }
    return 1;
}

/* FNV-1a over a state's bytes, its checksum field counted as zero */
static uint64_t state_checksum(const cedra_state *st) {
    cedra_state tmp;
    uint64_t h = 1469598103934665603ull;
    memcpy(&tmp, st, sizeof tmp);
    tmp.checksum = 0;
    const unsigned char *b = (const unsigned char *)&tmp;
    for (size_t i = 0; i < sizeof tmp; i++) h = (h ^ b[i]) * 1099511628211ull;
    return h;
}

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!FMUstate) return FAIL(c, "fmi2GetFMUstate: FMUstate is NULL");
    cedra_state *st = (cedra_state *)*FMUstate;
    if (!st) {
        st = (cedra_state *)c->alloc(1, sizeof(cedra_state));
        if (!st) {
            log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2GetFMUstate: out of memory");
            return fmi2Fatal;
        }
    } else if (!state_ok(c, "fmi2GetFMUstate", st)) {
        return fmi2Error;
    }
    memcpy(st, &c->s, sizeof *st);
    *FMUstate = (fmi2FMUstate)st;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate FMUstate) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!FMUstate) return FAIL(c, "fmi2SetFMUstate: FMUstate is NULL");
    if (!state_valid(c, "fmi2SetFMUstate", (const cedra_state *)FMUstate)) return fmi2Error;
    memcpy(&c->s, FMUstate, sizeof c->s);
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *FMUstate) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!FMUstate) return FAIL(c, "fmi2FreeFMUstate: FMUstate is NULL");
    if (*FMUstate) c->free(*FMUstate);
    *FMUstate = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate FMUstate, size_t *size) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!FMUstate || !size) return FAIL(c, "fmi2SerializedFMUstateSize: FMUstate or size is NULL");
    *size = sizeof(cedra_state);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate FMUstate, fmi2Byte serializedState[],
                                 size_t size) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!FMUstate || !serializedState) return FAIL(c, "fmi2SerializeFMUstate: FMUstate or serializedState is NULL");
    if (size != sizeof(cedra_state))
        return FAIL(c, "fmi2SerializeFMUstate: size %zu, the serialized state has %zu bytes", size,
                    sizeof(cedra_state));
    if (!state_ok(c, "fmi2SerializeFMUstate", (const cedra_state *)FMUstate)) return fmi2Error;
    cedra_state out;
    memcpy(&out, FMUstate, sizeof out);
    out.checksum = state_checksum(&out);
    memcpy(serializedState, &out, size);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    instance *c = (instance *)comp;
    cedra_state tmp;
    if (!c) return fmi2Error;
    if (!serializedState || !FMUstate)
        return FAIL(c, "fmi2DeSerializeFMUstate: serializedState or FMUstate is NULL");
    if (size != sizeof(cedra_state))
        return FAIL(c, "fmi2DeSerializeFMUstate: size %zu, a serialized state of %s has %zu bytes", size,
                    CEDRA_MODEL_IDENTIFIER, sizeof(cedra_state));
    memcpy(&tmp, serializedState, sizeof tmp);
    if (!state_ok(c, "fmi2DeSerializeFMUstate", &tmp)) return fmi2Error;
    if (tmp.checksum != state_checksum(&tmp))
        return FAIL(c, "fmi2DeSerializeFMUstate: refused, the checksum does not match the bytes (a damaged or "
                    "edited state)");
    if (!state_valid(c, "fmi2DeSerializeFMUstate", &tmp)) return fmi2Error;
    if (!*FMUstate) {
        *FMUstate = c->alloc(1, sizeof(cedra_state));
        if (!*FMUstate) {
            log_msg(c, fmi2Fatal, CAT_FATAL, "fmi2DeSerializeFMUstate: out of memory");
            return fmi2Fatal;
        }
    }
    memcpy(*FMUstate, &tmp, sizeof tmp);
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------- not supported */

fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[]) {
    (void)vUnknown_ref, (void)nUnknown, (void)vKnown_ref, (void)nKnown, (void)dvKnown, (void)dvUnknown;
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    return FAIL(c, "fmi2GetDirectionalDerivative: not supported (providesDirectionalDerivative=false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    return FAIL(c, "fmi2SetRealInputDerivatives: not supported (canInterpolateInputs=false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr, (void)nvr, (void)order, (void)value;
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    return FAIL(c, "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder=0)");
}

/* ------------------------------------------------------------------------------------------------- stepping */

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    cedra_state *s = &c->s;
    double t = currentCommunicationPoint, h = communicationStepSize;
    if (s->phase == PH_STEP_FAILED)
        return FAIL(c, "fmi2DoStep: the simulation was terminated at t=%.17g after a discarded step (restore a "
                    "state with fmi2SetFMUstate or call fmi2Reset)", s->last_good_time);
    if (!allowed(c, "fmi2DoStep", PH_STEP_COMPLETE)) return fmi2Error;
    if (!isfinite(h) || h <= 0) return FAIL(c, "fmi2DoStep: communicationStepSize = %g must be > 0", h);
    if (!isfinite(t) || fabs(t - s->time) > 1e-9 * fmax(1.0, fabs(s->time)))
        return FAIL(c, "fmi2DoStep: currentCommunicationPoint = %.17g, but the FMU is at t=%.17g", t, s->time);
    /* a step the FMU cannot resolve would "succeed" having done nothing */
    if (h < time_resolution(t) || !(t + h > t))
        return FAIL(c, "fmi2DoStep: communicationStepSize = %g is below the time resolution %g s at t=%.17g",
                    h, time_resolution(t), t);
    c->msg[0] = '\0';
    if (block_refuse_step(c, t, h)) return FAIL(c, "fmi2DoStep: refused: %s", c->msg);
    if (block_step(c, t, h) != fmi2OK) {   /* the block is back at t; the outputs are those at t */
        s->phase = PH_STEP_FAILED;
        s->terminated = 1;
        s->last_good_time = t;
        log_msg(c, fmi2Discard, CAT_DISCARD, "fmi2DoStep: step discarded at t=%.17g, simulation terminated: %s",
                t, c->msg);
        return fmi2Discard;
    }
    s->time = t + h;
    s->last_good_time = s->time;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    return FAIL(c, "fmi2CancelStep: not allowed in state %s (fmi2DoStep is synchronous, never pending)",
                phase_name(c->s.phase));
}

#define PH_STATUS (PH_STEP_COMPLETE | PH_STEP_FAILED | PH_TERMINATED)

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetStatus", PH_STATUS)) return fmi2Error;
    if (!value) return FAIL(c, "fmi2GetStatus: value is NULL");
    if (s == fmi2DoStepStatus) {   /* only meaningful after fmi2Pending, which this FMU never returns */
        *value = c->s.phase == PH_STEP_FAILED ? fmi2Discard : fmi2OK;
        return fmi2OK;
    }
    return FAIL(c, "fmi2GetStatus: status kind %d not supported", (int)s);
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetRealStatus", PH_STATUS)) return fmi2Error;
    if (!value) return FAIL(c, "fmi2GetRealStatus: value is NULL");
    if (s == fmi2LastSuccessfulTime) {
        *value = c->s.last_good_time;
        return fmi2OK;
    }
    return FAIL(c, "fmi2GetRealStatus: status kind %d not supported", (int)s);
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value) {
    instance *c = (instance *)comp;
    (void)value;
    if (!c) return fmi2Error;
    return FAIL(c, "fmi2GetIntegerStatus: status kind %d not supported", (int)s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetBooleanStatus", PH_STATUS)) return fmi2Error;
    if (!value) return FAIL(c, "fmi2GetBooleanStatus: value is NULL");
    if (s == fmi2Terminated) {
        *value = c->s.terminated ? fmi2True : fmi2False;
        return fmi2OK;
    }
    return FAIL(c, "fmi2GetBooleanStatus: status kind %d not supported", (int)s);
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value) {
    instance *c = (instance *)comp;
    if (!c) return fmi2Error;
    if (!allowed(c, "fmi2GetStringStatus", PH_STATUS)) return fmi2Error;
    if (!value) return FAIL(c, "fmi2GetStringStatus: value is NULL");
    if (s == fmi2PendingStatus) {
        *value = "";
        return fmi2OK;
    }
    return FAIL(c, "fmi2GetStringStatus: status kind %d not supported", (int)s);
}
