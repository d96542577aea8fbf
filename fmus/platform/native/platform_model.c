/* The model side of the native platform FMU: parameters, initial outputs and one macro step,
 * as PlatformSim does it (immersim.models.platform.simulator): the lazy at-rest skip, the washout
 * matrices of a new step size (washout.c), the one-call CasADi driver of the macro step, the
 * finiteness checks and the commit of the packed state. Messages are the Python build's.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "platform_instance.h"

void pf_log(inst_t* m, fmi2Status status, const char* category, const char* fmt, ...) {
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
const char* pf_repr(double x, char* buf) {
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


void* pf_alloc(inst_t* m, size_t n, size_t size) {
  return m->cb.allocateMemory ? m->cb.allocateMemory(n, size) : calloc(n, size);
}


void pf_release(inst_t* m, void* p) {
  if (!p) return;
  if (m->cb.freeMemory) m->cb.freeMemory(p); else free(p);
}

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
      snprintf(msg, size, "%s = %s must be > 0", PLATFORM_POSITIVE[k].label, pf_repr(v, b1));
      return msg;
    }
    if (PLATFORM_POSITIVE[k].vr == PLATFORM_VR_SIZE_Z) {  /* end of PlatformParams' > 0 checks */
      double pm = m->st.r[PLATFORM_VR_PAYLOAD_MASS], lo = m->st.r[PLATFORM_VR_STROKE_MIN];
      double hi = m->st.r[PLATFORM_VR_STROKE_MAX];
      if (pm < 0) { snprintf(msg, size, "PlatformParams.payload_mass = %s must be >= 0", pf_repr(pm, b1)); return msg; }
      if (!(lo < 0 && 0 < hi)) {
        snprintf(msg, size, "stroke limits [%s, %s] m must bracket 0", pf_repr(lo, b1), pf_repr(hi, b2));
        return msg;
      }
    }
  }
  if (m->st.i[PLATFORM_VR_SUBSTEPS] < 1) {
    snprintf(msg, size, "substeps = %d must be >= 1", m->st.i[PLATFORM_VR_SUBSTEPS]);
    return msg;
  }
  if (!(m->st.r[PLATFORM_VR_RTOL] > 0 && m->st.r[PLATFORM_VR_ATOL] > 0)) {
    snprintf(msg, size, "tolerances rtol = %s, atol = %s must be > 0", pf_repr(m->st.r[PLATFORM_VR_RTOL], b1),
             pf_repr(m->st.r[PLATFORM_VR_ATOL], b2));
    return msg;
  }
  return NULL;
}

fmi2Status platform_setup(inst_t* m) {
  char msg[512], b[32];
  size_t k;
  long long sz[4], best[4] = {0, 0, 1, 1};
  int vr, j;
  for (vr = 0; vr < PLATFORM_NVARS; ++vr) {
    const platform_var* v = &PLATFORM_VARS[vr];
    if (v->type == PT_REAL && (v->causality == PC_PARAMETER || v->causality == PC_INPUT) && !isfinite(m->st.r[vr])) {
      pf_log(m, fmi2Error, "logStatusError", "FmuInputError: %s: %s %s = %s is not finite at initialization (t = %g s)",
            m->name, v->causality == PC_PARAMETER ? "parameter" : "input", v->name, pf_repr(m->st.r[vr], b), m->st.time);
      return fmi2Error;
    }
  }
  if (bad_parameter(m, msg, sizeof msg)) {
    pf_log(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: %s", m->name, msg);
    return fmi2Error;
  }
  m->macro = NULL;
  for (k = 0; k < PLATFORM_NMACROS; ++k)
    if (strcmp(PLATFORM_MACROS[k].control, m->str[PLATFORM_VR_CONTROL]) == 0) m->macro = &PLATFORM_MACROS[k];
  if (!m->macro) {
    pf_log(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: control_mode = '%s' is not supported",
          m->name, m->str[PLATFORM_VR_CONTROL]);
    return fmi2Error;
  }
  for (j = 0; j < 4; ++j) {  /* work arrays: the largest of the generated functions' needs */
    m->macro->work[j](&sz[0], &sz[1], &sz[2], &sz[3]);
    for (k = 0; k < 4; ++k) if (sz[k] > best[k]) best[k] = sz[k];
  }
  if (best[0] < PLATFORM_DRIVER_SZ_ARG) best[0] = PLATFORM_DRIVER_SZ_ARG;
  if (best[1] < PLATFORM_DRIVER_SZ_RES) best[1] = PLATFORM_DRIVER_SZ_RES;
  pf_release(m, (void*) m->arg); pf_release(m, m->res); pf_release(m, m->iw); pf_release(m, m->w);
  m->arg = (const double**) pf_alloc(m, (size_t) best[0], sizeof(double*));
  m->res = (double**) pf_alloc(m, (size_t) best[1], sizeof(double*));
  m->iw = (long long*) pf_alloc(m, (size_t) best[2], sizeof(long long));
  m->w = (double*) pf_alloc(m, (size_t) best[3], sizeof(double));
  if (!m->arg || !m->res || !m->iw || !m->w) {
    pf_log(m, fmi2Fatal, "logStatusFatal", "%s: out of memory", m->name);
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
    pf_log(m, fmi2Error, "logStatusError", "ArithmeticError: %s: compiled platform macro step returned an error", m->name);
    return fmi2Error;
  }
  memcpy(m->st.out, m->out, sizeof m->out);
  m->st.rest = m->st.out[PLATFORM_OUT_AT_REST] != 0.0;
  m->st.ready = 1;
  write_outputs(m);
  return fmi2OK;
}

/* one macro step (PlatformSim.step_packed); a failure leaves the state as it was */
fmi2Status platform_step(inst_t* m, double t, double h) {
  char b1[32];
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
    pf_log(m, fmi2Error, "logStatusError", "ArithmeticError: %s: compiled platform macro step returned an error", m->name);
    return fmi2Discard;
  }
  if (rc == 2) {
    const double* ref = m->next + PLATFORM_OFF_RAW;
    pf_log(m, fmi2Error, "logStatusError",
          "OutsideWorkspaceError: %s: pose reference [%.4g %.4g %.4g %.4g %.4g %.4g] at t = %g s is outside the "
          "workspace (strokes %g..%g m, rod reach)", m->name, ref[0], ref[1], ref[2], ref[3], ref[4], ref[5], t,
          m->st.r[PLATFORM_VR_STROKE_MIN], m->st.r[PLATFORM_VR_STROKE_MAX]);
    return fmi2Discard;
  }
  if (m->out[PLATFORM_OUT_X_FINITE] == 0.0) {
    pf_log(m, fmi2Error, "logStatusError", "ArithmeticError: %s: platform state became non-finite in the step ending at "
          "t = %g s (integrator rk4): a rod lost its slider (out of reach) or the integration diverged", m->name, t + h);
    return fmi2Discard;
  }
  if (m->out[PLATFORM_OUT_STROKE_FINITE] == 0.0) {
    const double* q = m->next;
    pf_log(m, fmi2Error, "logStatusError", "OutsideWorkspaceError: %s: the platform left the rods' reach at t = %g s: "
          "pose [%.4g %.4g %.4g %.4g %.4g %.4g]", m->name, t + h, q[0], q[1], q[2], q[3], q[4], q[5]);
    return fmi2Discard;
  }
  for (k = 0; k < PLATFORM_NREAL_OUT; ++k)
    if (!isfinite(m->out[k])) {
      pf_log(m, fmi2Error, "logStatusError", "FmuModelError: %s: output %s = %s at t = %g s is not finite", m->name,
            PLATFORM_VARS[PLATFORM_OUT_VR[k]].name, pf_repr(m->out[k], b1), t + h);
      return fmi2Discard;
    }
  memcpy(m->st.state, m->next, sizeof m->next);
  memcpy(m->st.out, m->out, sizeof m->out);
  m->st.rest = m->out[PLATFORM_OUT_AT_REST] != 0.0;
  write_outputs(m);
  return fmi2OK;
}

