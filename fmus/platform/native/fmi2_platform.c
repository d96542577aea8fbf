/* FMI 2.0 co-simulation layer of the native platform build.
 *
 * The numerics are CasADi's generated C of the platform macro step (one translation unit per
 * controller, compiled from immersim.models.platform.macrostep exactly as the Python build
 * compiles it) and washout.c; this file holds the variables, the state machine, the master's
 * checks and the FMU state. platform_native.h is generated from the Var declarations of
 * fmus/platform/platform_fmu.py (names, value references, types, causalities, start values) and
 * from the packed layouts of macrostep.py, so the two builds cannot drift. One step does what
 * PlatformSim.step_packed does: the lazy at-rest skip, the washout matrices of a new step size,
 * the one-call driver, the finiteness checks and the commit of the packed state.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#define PLATFORM_NATIVE_TABLES
#include "platform_native.h"

enum { PH_INSTANTIATED, PH_INIT, PH_STEP, PH_TERMINATED, PH_ERROR };

/* everything an FMU state holds (plain data: copied and serialized as bytes) */
typedef struct {
  double r[PLATFORM_NVARS];  /* Real values by value reference */
  int i[PLATFORM_NVARS];     /* Integer and Boolean values by value reference */
  double time;
  double state[PLATFORM_NSTATE], out[PLATFORM_NOUT];
  int rest, ready;
} platform_state;

typedef struct {
  platform_state st;
  char* str[PLATFORM_NVARS];
  char* name;
  fmi2CallbackFunctions cb;
  int logging, phase;
  const platform_macro* macro;
  double next[PLATFORM_NSTATE], s[PLATFORM_NIN], ctrl[PLATFORM_NCTRL], wm[PLATFORM_NWM];
  double p[PLATFORM_NP], c[PLATFORM_NC], wp[PLATFORM_NWP], out[PLATFORM_NOUT], inside, clamped;
  double h_wm;
  int lazy;
  long long* iw;
  double* w;
  const double** arg;
  double** res;
} inst_t;

static const char SERIAL_MAGIC[16] = "immersim-pfn-v1";

static void logf_(inst_t* m, fmi2Status status, const char* category, const char* fmt, ...) {
  char msg[1024], esc[2048];
  size_t i, k = 0;
  va_list ap;
  if (!m || !m->cb.logger || (status == fmi2OK && !m->logging)) return;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  for (i = 0; msg[i] && k + 2 < sizeof esc; ++i) {  /* the logger takes a format string */
    if (msg[i] == '%') esc[k++] = '%';
    esc[k++] = msg[i];
  }
  esc[k] = 0;
  m->cb.logger(m->cb.componentEnvironment, m->name, status, category, esc);
}

/* Python's repr of a float: the shortest round-trip digits, with ".0" for an integral value */
static const char* repr(double x, char* buf) {
  int prec;
  if (isnan(x)) return strcpy(buf, "nan");
  if (isinf(x)) return strcpy(buf, x > 0 ? "inf" : "-inf");
  for (prec = 1; prec <= 17; ++prec) {
    snprintf(buf, 32, "%.*g", prec, x);
    if (strtod(buf, NULL) == x) break;
  }
  if (!strpbrk(buf, ".e")) strcat(buf, ".0");
  return buf;
}

static int find_choice(const char* const* list, const char* v) {
  int k;
  for (k = 0; list[k]; ++k) if (strcmp(list[k], v) == 0) return k;
  return -1;
}

static void* alloc(inst_t* m, size_t n, size_t size) {
  return m->cb.allocateMemory ? m->cb.allocateMemory(n, size) : calloc(n, size);
}

static void release(inst_t* m, void* p) {
  if (!p) return;
  if (m->cb.freeMemory) m->cb.freeMemory(p); else free(p);
}

static char* dup_string(inst_t* m, const char* s) {
  size_t n = strlen(s) + 1;
  char* out = (char*) alloc(m, n, 1);
  if (out) memcpy(out, s, n);
  return out;
}

static void set_start_values(inst_t* m) {
  int vr;
  for (vr = 0; vr < PLATFORM_NVARS; ++vr) {
    const platform_var* v = &PLATFORM_VARS[vr];
    m->st.r[vr] = v->real_start;
    m->st.i[vr] = v->int_start;
    if (v->type == PT_STRING) {
      release(m, m->str[vr]);
      m->str[vr] = dup_string(m, v->str_start);
    }
  }
  m->st.time = 0.0;
  m->st.ready = 0;
  m->h_wm = -1.0;
}

static int allowed(inst_t* m, const char* fn, unsigned phases) {
  static const char* const names[] = {"instantiated", "initialization mode", "step mode", "terminated", "error"};
  if (!m) return 0;
  if (phases & (1u << m->phase)) return 1;
  logf_(m, fmi2Error, "logStatusError", "%s: %s is not allowed in state %s", m->name, fn, names[m->phase]);
  return 0;
}
#define IN(ph) (1u << (ph))
#define ANY_BUT_ERROR (IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP) | IN(PH_TERMINATED))
#define READABLE (IN(PH_INIT) | IN(PH_STEP) | IN(PH_TERMINATED) | IN(PH_ERROR))

/* -- the model ---------------------------------------------------------------------------- */
static void write_outputs(inst_t* m) {
  int k;
  for (k = 0; k < PLATFORM_NREAL_OUT; ++k) m->st.r[PLATFORM_OUT_VR[k]] = m->st.out[k];
  for (k = 0; k < PLATFORM_NFLAGS; ++k) m->st.i[PLATFORM_FLAG_VR[k]] = m->st.out[PLATFORM_FLAG_OUT[k]] != 0.0;
}

static int run_post(inst_t* m) {
  const double** a = m->arg;
  double* n = m->next;
  a[0] = n + PLATFORM_OFF_X; a[1] = n + PLATFORM_OFF_U; a[2] = m->p; a[3] = m->c; a[4] = n + PLATFORM_OFF_RAW;
  a[5] = n + PLATFORM_OFF_REACH; a[6] = &m->clamped; a[7] = m->ctrl; a[8] = n + PLATFORM_OFF_W;
  m->res[0] = m->out;
  return m->macro->post(a, m->res, m->iw, m->w, 0);
}

static const char* bad_parameter(inst_t* m, char* msg, size_t size) {
  /* the checks of SimConfig and its dataclasses, in their order and with their messages */
  char b1[32], b2[32];
  int k;
  for (k = 0; PLATFORM_POSITIVE[k].label; ++k) {
    double v = m->st.r[PLATFORM_POSITIVE[k].vr];
    if (!(v > 0)) {
      snprintf(msg, size, "%s = %s must be > 0", PLATFORM_POSITIVE[k].label, repr(v, b1));
      return msg;
    }
    if (PLATFORM_POSITIVE[k].vr == PLATFORM_VR_SIZE_Z) {  /* end of PlatformParams' > 0 checks */
      double pm = m->st.r[PLATFORM_VR_PAYLOAD_MASS], lo = m->st.r[PLATFORM_VR_STROKE_MIN];
      double hi = m->st.r[PLATFORM_VR_STROKE_MAX];
      if (pm < 0) { snprintf(msg, size, "PlatformParams.payload_mass = %s must be >= 0", repr(pm, b1)); return msg; }
      if (!(lo < 0 && 0 < hi)) {
        snprintf(msg, size, "stroke limits [%s, %s] m must bracket 0", repr(lo, b1), repr(hi, b2));
        return msg;
      }
    }
  }
  if (m->st.i[PLATFORM_VR_SUBSTEPS] < 1) {
    snprintf(msg, size, "substeps = %d must be >= 1", m->st.i[PLATFORM_VR_SUBSTEPS]);
    return msg;
  }
  if (!(m->st.r[PLATFORM_VR_RTOL] > 0 && m->st.r[PLATFORM_VR_ATOL] > 0)) {
    snprintf(msg, size, "tolerances rtol = %s, atol = %s must be > 0", repr(m->st.r[PLATFORM_VR_RTOL], b1),
             repr(m->st.r[PLATFORM_VR_ATOL], b2));
    return msg;
  }
  return NULL;
}

static fmi2Status setup_model(inst_t* m) {
  char msg[512], b[32];
  size_t k;
  long long sz[4], best[4] = {0, 0, 1, 1};
  int vr, j;
  for (vr = 0; vr < PLATFORM_NVARS; ++vr) {
    const platform_var* v = &PLATFORM_VARS[vr];
    if (v->type == PT_REAL && (v->causality == PC_PARAMETER || v->causality == PC_INPUT) && !isfinite(m->st.r[vr])) {
      logf_(m, fmi2Error, "logStatusError", "FmuInputError: %s: %s %s = %s is not finite at initialization (t = %g s)",
            m->name, v->causality == PC_PARAMETER ? "parameter" : "input", v->name, repr(m->st.r[vr], b), m->st.time);
      return fmi2Error;
    }
  }
  if (bad_parameter(m, msg, sizeof msg)) {
    logf_(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: %s", m->name, msg);
    return fmi2Error;
  }
  m->macro = NULL;
  for (k = 0; k < PLATFORM_NMACROS; ++k)
    if (strcmp(PLATFORM_MACROS[k].control, m->str[PLATFORM_VR_CONTROL]) == 0) m->macro = &PLATFORM_MACROS[k];
  if (!m->macro) {
    logf_(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: control_mode = '%s' is not supported",
          m->name, m->str[PLATFORM_VR_CONTROL]);
    return fmi2Error;
  }
  for (j = 0; j < 4; ++j) {  /* work arrays: the largest of the generated functions' needs */
    m->macro->work[j](&sz[0], &sz[1], &sz[2], &sz[3]);
    for (k = 0; k < 4; ++k) if (sz[k] > best[k]) best[k] = sz[k];
  }
  if (best[0] < PLATFORM_DRIVER_SZ_ARG) best[0] = PLATFORM_DRIVER_SZ_ARG;
  if (best[1] < PLATFORM_DRIVER_SZ_RES) best[1] = PLATFORM_DRIVER_SZ_RES;
  release(m, (void*) m->arg); release(m, m->res); release(m, m->iw); release(m, m->w);
  m->arg = (const double**) alloc(m, (size_t) best[0], sizeof(double*));
  m->res = (double**) alloc(m, (size_t) best[1], sizeof(double*));
  m->iw = (long long*) alloc(m, (size_t) best[2], sizeof(long long));
  m->w = (double*) alloc(m, (size_t) best[3], sizeof(double));
  if (!m->arg || !m->res || !m->iw || !m->w) {
    logf_(m, fmi2Fatal, "logStatusFatal", "%s: out of memory", m->name);
    return fmi2Fatal;
  }
  for (k = 0; k < PLATFORM_NP; ++k) m->p[k] = m->st.r[PLATFORM_P_VR[k]];
  for (k = 0; k < PLATFORM_NC; ++k) m->c[k] = m->st.r[PLATFORM_C_VR[k]];
  for (k = 0; k < PLATFORM_NWP; ++k) m->wp[k] = m->st.r[PLATFORM_WASHOUT_VR[k]];
  m->ctrl[0] = strcmp(m->str[PLATFORM_VR_CUEING], "washout") == 0;
  m->ctrl[1] = 0.0;
  m->ctrl[2] = (double) m->st.i[PLATFORM_VR_SUBSTEPS];
  m->ctrl[3] = m->st.r[PLATFORM_VR_COS_BETA_MIN];
  m->ctrl[4] = strcmp(m->str[PLATFORM_VR_ON_WORKSPACE], "clamp") == 0;
  m->lazy = strcmp(m->str[PLATFORM_VR_CONTROL], "direct") != 0;
  m->h_wm = -1.0;
  memset(m->st.state, 0, sizeof m->st.state);
  for (k = 0; k < 6; ++k) m->st.state[PLATFORM_OFF_REACH + k] = 1.0;
  memcpy(m->next, m->st.state, sizeof m->next);
  m->clamped = 0.0;
  if (run_post(m)) {
    logf_(m, fmi2Error, "logStatusError", "ArithmeticError: %s: compiled platform macro step returned an error", m->name);
    return fmi2Error;
  }
  memcpy(m->st.out, m->out, sizeof m->out);
  m->st.rest = m->st.out[PLATFORM_OUT_AT_REST] != 0.0;
  m->st.ready = 1;
  write_outputs(m);
  return fmi2OK;
}

/* one macro step (PlatformSim.step_packed); a failure leaves the state as it was */
static fmi2Status model_step(inst_t* m, double t, double h) {
  char b1[32], b2[32];
  int k, any = 0, rc;
  for (k = 0; k < PLATFORM_NIN; ++k) {
    m->s[k] = m->st.r[PLATFORM_IN_VR[k]];
    any |= m->s[k] != 0.0;
  }
  if (m->st.rest && m->lazy && !any) return fmi2OK;  /* lazy: nothing moves, outputs stay */
  if (h != m->h_wm) {
    platform_washout_matrices(m->wp, h, m->wm);
    m->ctrl[1] = h;
    m->h_wm = h;
  }
  {
    const double* a[6];
    double* r[3];
    a[0] = m->st.state; a[1] = m->s; a[2] = m->ctrl; a[3] = m->wm; a[4] = m->p; a[5] = m->c;
    r[0] = m->next; r[1] = m->out; r[2] = &m->inside;
    rc = m->macro->driver(a, r, m->iw, m->w);
  }
  if (rc == 1) {
    logf_(m, fmi2Error, "logStatusError", "ArithmeticError: %s: compiled platform macro step returned an error", m->name);
    return fmi2Discard;
  }
  if (rc == 2) {
    const double* ref = m->next + PLATFORM_OFF_RAW;
    logf_(m, fmi2Error, "logStatusError",
          "OutsideWorkspaceError: %s: pose reference [%.4g %.4g %.4g %.4g %.4g %.4g] at t = %g s is outside the "
          "workspace (strokes %g..%g m, rod reach)", m->name, ref[0], ref[1], ref[2], ref[3], ref[4], ref[5], t,
          m->st.r[PLATFORM_VR_STROKE_MIN], m->st.r[PLATFORM_VR_STROKE_MAX]);
    return fmi2Discard;
  }
  if (m->out[PLATFORM_OUT_X_FINITE] == 0.0) {
    logf_(m, fmi2Error, "logStatusError", "ArithmeticError: %s: platform state became non-finite in the step ending at "
          "t = %g s (integrator rk4): a rod lost its slider (out of reach) or the integration diverged", m->name, t + h);
    return fmi2Discard;
  }
  if (m->out[PLATFORM_OUT_STROKE_FINITE] == 0.0) {
    const double* q = m->next;
    logf_(m, fmi2Error, "logStatusError", "OutsideWorkspaceError: %s: the platform left the rods' reach at t = %g s: "
          "pose [%.4g %.4g %.4g %.4g %.4g %.4g]", m->name, t + h, q[0], q[1], q[2], q[3], q[4], q[5]);
    return fmi2Discard;
  }
  for (k = 0; k < PLATFORM_NREAL_OUT; ++k)
    if (!isfinite(m->out[k])) {
      logf_(m, fmi2Error, "logStatusError", "FmuModelError: %s: output %s = %s at t = %g s is not finite", m->name,
            PLATFORM_VARS[PLATFORM_OUT_VR[k]].name, repr(m->out[k], b1), t + h);
      return fmi2Discard;
    }
  (void) b2;
  memcpy(m->st.state, m->next, sizeof m->next);
  memcpy(m->st.out, m->out, sizeof m->out);
  m->st.rest = m->out[PLATFORM_OUT_AT_REST] != 0.0;
  write_outputs(m);
  return fmi2OK;
}

/* -- FMI 2.0 ------------------------------------------------------------------------------ */
const char* fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char* fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t n, const fmi2String cats[]) {
  inst_t* m = (inst_t*) c;
  (void) n; (void) cats;
  if (!m) return fmi2Error;
  m->logging = loggingOn != 0;
  return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions* cb, fmi2Boolean visible, fmi2Boolean loggingOn) {
  inst_t* m;
  (void) resources; (void) visible;
  if (!cb || !cb->logger) return NULL;
  if (!name || !name[0]) {
    cb->logger(cb->componentEnvironment, "?", fmi2Error, "logStatusError", "fmi2Instantiate: no instance name");
    return NULL;
  }
  if (type != fmi2CoSimulation) {
    cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
               "fmi2Instantiate: " PLATFORM_MODEL_NAME " is a co-simulation FMU only");
    return NULL;
  }
  if (!guid || strcmp(guid, PLATFORM_GUID) != 0) {
    cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
               "fmi2Instantiate: GUID does not match this FMU's modelDescription.xml");
    return NULL;
  }
  m = (inst_t*) (cb->allocateMemory ? cb->allocateMemory(1, sizeof(inst_t)) : calloc(1, sizeof(inst_t)));
  if (!m) return NULL;
  memset(m, 0, sizeof *m);
  m->cb = *cb;
  m->logging = loggingOn != 0;
  m->name = dup_string(m, name);
  set_start_values(m);
  m->phase = PH_INSTANTIATED;
  return m;
}

void fmi2FreeInstance(fmi2Component c) {
  inst_t* m = (inst_t*) c;
  int vr;
  if (!m) return;
  for (vr = 0; vr < PLATFORM_NVARS; ++vr) release(m, m->str[vr]);
  release(m, (void*) m->arg); release(m, m->res); release(m, m->iw); release(m, m->w);
  release(m, m->name);
  release(m, m);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
  inst_t* m = (inst_t*) c;
  (void) tolDefined; (void) tol; (void) stopDefined; (void) stop;
  if (!allowed(m, "fmi2SetupExperiment", IN(PH_INSTANTIATED))) return fmi2Error;
  m->st.time = start;
  return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
  inst_t* m = (inst_t*) c;
  if (!allowed(m, "fmi2EnterInitializationMode", IN(PH_INSTANTIATED))) return fmi2Error;
  m->phase = PH_INIT;
  return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
  inst_t* m = (inst_t*) c;
  fmi2Status s;
  if (!allowed(m, "fmi2ExitInitializationMode", IN(PH_INIT))) return fmi2Error;
  s = setup_model(m);
  m->phase = s == fmi2OK ? PH_STEP : PH_ERROR;
  return s;
}

fmi2Status fmi2Terminate(fmi2Component c) {
  inst_t* m = (inst_t*) c;
  if (!allowed(m, "fmi2Terminate", IN(PH_STEP) | IN(PH_ERROR))) return fmi2Error;
  m->phase = PH_TERMINATED;
  return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
  inst_t* m = (inst_t*) c;
  if (!m) return fmi2Error;
  set_start_values(m);
  m->phase = PH_INSTANTIATED;
  return fmi2OK;
}

static int check_vr(inst_t* m, const char* fn, fmi2ValueReference vr, int type) {
  static const char* const tn[] = {"Real", "Integer", "Boolean", "String"};
  if (vr >= PLATFORM_NVARS) {
    logf_(m, fmi2Error, "logStatusError", "%s: %s: no variable with valueReference %u", m->name, fn, (unsigned) vr);
    return 0;
  }
  if (PLATFORM_VARS[vr].type != type) {
    logf_(m, fmi2Error, "logStatusError", "%s: %s: valueReference %u (%s) is not %s", m->name, fn, (unsigned) vr,
          PLATFORM_VARS[vr].name, tn[type]);
    return 0;
  }
  return 1;
}

/* may the variable be set now (FMI 2.0 table of allowed calls, by causality) */
static int settable(inst_t* m, const char* fn, fmi2ValueReference vr) {
  const platform_var* v = &PLATFORM_VARS[vr];
  int ph = m->phase;
  if (v->causality == PC_INPUT && (ph == PH_INSTANTIATED || ph == PH_INIT || ph == PH_STEP)) return 1;
  if (v->causality == PC_PARAMETER && (ph == PH_INSTANTIATED || ph == PH_INIT)) return 1;
  logf_(m, fmi2Error, "logStatusError", "%s: %s: %s %s cannot be set %s", m->name, fn,
        v->causality == PC_OUTPUT ? "output" : v->causality == PC_PARAMETER ? "parameter" : "variable", v->name,
        v->causality == PC_OUTPUT ? "by the master" : "after initialization");
  return 0;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2GetReal", READABLE | IN(PH_INSTANTIATED))) return fmi2Error;
  for (k = 0; k < n; ++k) {
    if (!check_vr(m, "fmi2GetReal", vr[k], PT_REAL)) return fmi2Error;
    value[k] = m->st.r[vr[k]];
  }
  return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2GetInteger", READABLE | IN(PH_INSTANTIATED))) return fmi2Error;
  for (k = 0; k < n; ++k) {
    if (!check_vr(m, "fmi2GetInteger", vr[k], PT_INTEGER)) return fmi2Error;
    value[k] = m->st.i[vr[k]];
  }
  return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2GetBoolean", READABLE | IN(PH_INSTANTIATED))) return fmi2Error;
  for (k = 0; k < n; ++k) {
    if (!check_vr(m, "fmi2GetBoolean", vr[k], PT_BOOLEAN)) return fmi2Error;
    value[k] = m->st.i[vr[k]] ? fmi2True : fmi2False;
  }
  return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2GetString", READABLE | IN(PH_INSTANTIATED))) return fmi2Error;
  for (k = 0; k < n; ++k) {
    if (!check_vr(m, "fmi2GetString", vr[k], PT_STRING)) return fmi2Error;
    value[k] = m->str[vr[k]];
  }
  return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2SetReal", IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP))) return fmi2Error;
  for (k = 0; k < n; ++k)
    if (!check_vr(m, "fmi2SetReal", vr[k], PT_REAL) || !settable(m, "fmi2SetReal", vr[k])) return fmi2Error;
  for (k = 0; k < n; ++k) m->st.r[vr[k]] = value[k];  /* non-finite inputs are refused by fmi2DoStep */
  return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2SetInteger", IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP))) return fmi2Error;
  for (k = 0; k < n; ++k)
    if (!check_vr(m, "fmi2SetInteger", vr[k], PT_INTEGER) || !settable(m, "fmi2SetInteger", vr[k])) return fmi2Error;
  for (k = 0; k < n; ++k) m->st.i[vr[k]] = value[k];
  return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  if (!allowed(m, "fmi2SetBoolean", IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP))) return fmi2Error;
  for (k = 0; k < n; ++k)
    if (!check_vr(m, "fmi2SetBoolean", vr[k], PT_BOOLEAN) || !settable(m, "fmi2SetBoolean", vr[k])) return fmi2Error;
  for (k = 0; k < n; ++k) m->st.i[vr[k]] = value[k] != fmi2False;
  return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) {
  inst_t* m = (inst_t*) c;
  size_t k;
  int j;
  if (!allowed(m, "fmi2SetString", IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP))) return fmi2Error;
  for (k = 0; k < n; ++k) {
    if (!check_vr(m, "fmi2SetString", vr[k], PT_STRING) || !settable(m, "fmi2SetString", vr[k])) return fmi2Error;
    for (j = 0; PLATFORM_CHOICES[j].vr >= 0 && PLATFORM_CHOICES[j].vr != (int) vr[k]; ++j) {}
    if (PLATFORM_CHOICES[j].vr >= 0) {
      const platform_choice* ch = &PLATFORM_CHOICES[j];
      const char* v = value[k] ? value[k] : "";
      if (find_choice(ch->supported, v) < 0) {
        if (find_choice(ch->python, v) >= 0)
          logf_(m, fmi2Error, "logStatusError", "ValueError: %s: parameter %s = '%s' is not supported by the native "
                "build (it supports %s); the Python build (fmu = \"platform\") has it", m->name,
                PLATFORM_VARS[vr[k]].name, v, ch->supported_text);
        else
          logf_(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: %s = '%s' is not one of %s", m->name,
                PLATFORM_VARS[vr[k]].name, v, ch->python_text);
        return fmi2Error;
      }
    }
  }
  for (k = 0; k < n; ++k) {
    char* s = dup_string(m, value[k] ? value[k] : "");
    if (!s) return fmi2Fatal;
    release(m, m->str[vr[k]]);
    m->str[vr[k]] = s;
  }
  return fmi2OK;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
  inst_t* m = (inst_t*) c;
  char b1[32], b2[32];
  int k;
  fmi2Status s;
  (void) noSetPrior;
  if (!allowed(m, "fmi2DoStep", IN(PH_STEP))) return fmi2Error;
  if (!(h > 0.0)) {
    logf_(m, fmi2Error, "logStatusError", "FmuInputError: %s: communication step size %s s at t = %g s must be > 0",
          m->name, repr(h, b1), t);
    return fmi2Discard;
  }
  if (fabs(t - m->st.time) > PLATFORM_TIME_RTOL * fmax(1.0, fabs(m->st.time))) {
    logf_(m, fmi2Error, "logStatusError", "FmuInputError: %s: doStep current time t = %s s but the FMU is at t = %s s",
          m->name, repr(t, b1), repr(m->st.time, b2));
    return fmi2Discard;
  }
  for (k = 0; k < PLATFORM_NIN; ++k) {
    double v = m->st.r[PLATFORM_IN_VR[k]];
    if (!isfinite(v)) {
      logf_(m, fmi2Error, "logStatusError", "FmuInputError: %s: input %s = %s at t = %g s is not finite", m->name,
            PLATFORM_VARS[PLATFORM_IN_VR[k]].name, repr(v, b1), t);
      return fmi2Discard;
    }
  }
  s = model_step(m, t, h);
  if (s == fmi2OK) m->st.time = t + h;
  return s;
}

fmi2Status fmi2CancelStep(fmi2Component c) { (void) c; return fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status* value) {
  (void) c; (void) s; *value = fmi2OK; return fmi2Discard;
}
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real* value) {
  inst_t* m = (inst_t*) c;
  if (m && s == fmi2LastSuccessfulTime) { *value = m->st.time; return fmi2OK; }
  return fmi2Discard;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer* value) {
  (void) c; (void) s; (void) value; return fmi2Discard;
}
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean* value) {
  (void) c;
  if (s == fmi2Terminated) { *value = fmi2False; return fmi2OK; }
  return fmi2Discard;
}
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String* value) {
  (void) c; (void) s; (void) value; return fmi2Discard;
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real value[]) {
  inst_t* m = (inst_t*) c;
  (void) vr; (void) n; (void) order; (void) value;
  logf_(m, fmi2Error, "logStatusError", "%s: fmi2SetRealInputDerivatives is not supported", m ? m->name : "?");
  return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
  inst_t* m = (inst_t*) c;
  (void) vr; (void) n; (void) order; (void) value;
  logf_(m, fmi2Error, "logStatusError", "%s: fmi2GetRealOutputDerivatives is not supported", m ? m->name : "?");
  return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
  inst_t* m = (inst_t*) c;
  (void) u; (void) nu; (void) z; (void) nz; (void) du; (void) dz;
  logf_(m, fmi2Error, "logStatusError", "%s: fmi2GetDirectionalDerivative is not supported", m ? m->name : "?");
  return fmi2Error;
}

/* -- FMU state: the plain-data platform_state (strings are parameters, fixed after initialization) */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* state) {
  inst_t* m = (inst_t*) c;
  platform_state* s;
  if (!allowed(m, "fmi2GetFMUstate", ANY_BUT_ERROR)) return fmi2Error;
  s = (platform_state*) (*state ? *state : alloc(m, 1, sizeof(platform_state)));
  if (!s) return fmi2Fatal;
  *s = m->st;
  *state = s;
  return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
  inst_t* m = (inst_t*) c;
  const platform_state* s = (const platform_state*) state;
  if (!allowed(m, "fmi2SetFMUstate", ANY_BUT_ERROR)) return fmi2Error;
  if (!s) return fmi2Error;
  if (s->ready && !m->st.ready) {
    logf_(m, fmi2Error, "logStatusError", "%s: fmi2SetFMUstate: the state was taken after initialization, this "
          "instance is not initialized", m->name);
    return fmi2Error;
  }
  m->st = *s;
  return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* state) {
  inst_t* m = (inst_t*) c;
  if (!m || !state) return fmi2Error;
  release(m, *state);
  *state = NULL;
  return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t* size) {
  (void) c; (void) state;
  *size = sizeof SERIAL_MAGIC + sizeof(platform_state);
  return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[], size_t size) {
  inst_t* m = (inst_t*) c;
  if (!m || !state) return fmi2Error;
  if (size < sizeof SERIAL_MAGIC + sizeof(platform_state)) {
    logf_(m, fmi2Error, "logStatusError", "%s: fmi2SerializeFMUstate: buffer of %zu bytes is too small", m->name, size);
    return fmi2Error;
  }
  memcpy(bytes, SERIAL_MAGIC, sizeof SERIAL_MAGIC);
  memcpy(bytes + sizeof SERIAL_MAGIC, state, sizeof(platform_state));
  return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size, fmi2FMUstate* state) {
  inst_t* m = (inst_t*) c;
  platform_state* s;
  if (!m) return fmi2Error;
  if (size != sizeof SERIAL_MAGIC + sizeof(platform_state) || memcmp(bytes, SERIAL_MAGIC, sizeof SERIAL_MAGIC) != 0) {
    logf_(m, fmi2Error, "logStatusError", "%s: fmi2DeSerializeFMUstate: %zu bytes are not a state of this FMU "
          "build", m->name, size);
    return fmi2Error;
  }
  s = (platform_state*) (*state ? *state : alloc(m, 1, sizeof(platform_state)));
  if (!s) return fmi2Fatal;
  memcpy(s, bytes + sizeof SERIAL_MAGIC, sizeof(platform_state));
  *state = s;
  return fmi2OK;
}
