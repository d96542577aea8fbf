/* FMI 2.0 co-simulation layer of the native platform build: variables, state machine, the master's
 * checks and the FMU state.
 *
 * The numerics are CasADi's generated C of the platform macro step (one translation unit per
 * controller, generated from immersim.models.platform.macrostep exactly as the Python build
 * generates it), washout.c and platform_model.c (one step as PlatformSim does it).
 * platform_native.h is generated from the Var declarations of fmus/platform/platform_fmu.py (names,
 * value references, types, causalities, start values) and from the packed layouts of macrostep.py,
 * so the two builds cannot drift. Master errors return fmi2Discard with the Python build's message.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "platform_instance.h"

static const char SERIAL_MAGIC[16] = "immersim-pfn-v1";


static int find_choice(const char* const* list, const char* v) {
  int k;
  for (k = 0; list[k]; ++k) if (strcmp(list[k], v) == 0) return k;
  return -1;
}



static char* dup_string(inst_t* m, const char* s) {
  size_t n = strlen(s) + 1;
  char* out = (char*) pf_alloc(m, n, 1);
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
      pf_release(m, m->str[vr]);
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
  pf_log(m, fmi2Error, "logStatusError", "%s: %s is not allowed in state %s", m->name, fn, names[m->phase]);
  return 0;
}
#define IN(ph) (1u << (ph))
#define ANY_BUT_ERROR (IN(PH_INSTANTIATED) | IN(PH_INIT) | IN(PH_STEP) | IN(PH_TERMINATED))
#define READABLE (IN(PH_INIT) | IN(PH_STEP) | IN(PH_TERMINATED) | IN(PH_ERROR))

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
  for (vr = 0; vr < PLATFORM_NVARS; ++vr) pf_release(m, m->str[vr]);
  pf_release(m, (void*) m->arg); pf_release(m, m->res); pf_release(m, m->iw); pf_release(m, m->w);
  pf_release(m, m->name);
  pf_release(m, m);
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
  s = platform_setup(m);
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
    pf_log(m, fmi2Error, "logStatusError", "%s: %s: no variable with valueReference %u", m->name, fn, (unsigned) vr);
    return 0;
  }
  if (PLATFORM_VARS[vr].type != type) {
    pf_log(m, fmi2Error, "logStatusError", "%s: %s: valueReference %u (%s) is not %s", m->name, fn, (unsigned) vr,
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
  pf_log(m, fmi2Error, "logStatusError", "%s: %s: %s %s cannot be set %s", m->name, fn,
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
          pf_log(m, fmi2Error, "logStatusError", "ValueError: %s: parameter %s = '%s' is not supported by the native "
                "build (it supports %s); the Python build (fmu = \"platform\") has it", m->name,
                PLATFORM_VARS[vr[k]].name, v, ch->supported_text);
        else
          pf_log(m, fmi2Error, "logStatusError", "ValueError: %s: bad parameter: %s = '%s' is not one of %s", m->name,
                PLATFORM_VARS[vr[k]].name, v, ch->python_text);
        return fmi2Error;
      }
    }
  }
  for (k = 0; k < n; ++k) {
    char* s = dup_string(m, value[k] ? value[k] : "");
    if (!s) return fmi2Fatal;
    pf_release(m, m->str[vr[k]]);
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
    pf_log(m, fmi2Error, "logStatusError", "FmuInputError: %s: communication step size %s s at t = %g s must be > 0",
          m->name, pf_repr(h, b1), t);
    return fmi2Discard;
  }
  if (fabs(t - m->st.time) > PLATFORM_TIME_RTOL * fmax(1.0, fabs(m->st.time))) {
    pf_log(m, fmi2Error, "logStatusError", "FmuInputError: %s: doStep current time t = %s s but the FMU is at t = %s s",
          m->name, pf_repr(t, b1), pf_repr(m->st.time, b2));
    return fmi2Discard;
  }
  for (k = 0; k < PLATFORM_NIN; ++k) {
    double v = m->st.r[PLATFORM_IN_VR[k]];
    if (!isfinite(v)) {
      pf_log(m, fmi2Error, "logStatusError", "FmuInputError: %s: input %s = %s at t = %g s is not finite", m->name,
            PLATFORM_VARS[PLATFORM_IN_VR[k]].name, pf_repr(v, b1), t);
      return fmi2Discard;
    }
  }
  s = platform_step(m, t, h);
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
  pf_log(m, fmi2Error, "logStatusError", "%s: fmi2SetRealInputDerivatives is not supported", m ? m->name : "?");
  return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real value[]) {
  inst_t* m = (inst_t*) c;
  (void) vr; (void) n; (void) order; (void) value;
  pf_log(m, fmi2Error, "logStatusError", "%s: fmi2GetRealOutputDerivatives is not supported", m ? m->name : "?");
  return fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz, const fmi2Real du[], fmi2Real dz[]) {
  inst_t* m = (inst_t*) c;
  (void) u; (void) nu; (void) z; (void) nz; (void) du; (void) dz;
  pf_log(m, fmi2Error, "logStatusError", "%s: fmi2GetDirectionalDerivative is not supported", m ? m->name : "?");
  return fmi2Error;
}

/* -- FMU state: the plain-data platform_state (strings are parameters, fixed after initialization) */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate* state) {
  inst_t* m = (inst_t*) c;
  platform_state* s;
  if (!allowed(m, "fmi2GetFMUstate", ANY_BUT_ERROR)) return fmi2Error;
  s = (platform_state*) (*state ? *state : pf_alloc(m, 1, sizeof(platform_state)));
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
    pf_log(m, fmi2Error, "logStatusError", "%s: fmi2SetFMUstate: the state was taken after initialization, this "
          "instance is not initialized", m->name);
    return fmi2Error;
  }
  m->st = *s;
  return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate* state) {
  inst_t* m = (inst_t*) c;
  if (!m || !state) return fmi2Error;
  pf_release(m, *state);
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
    pf_log(m, fmi2Error, "logStatusError", "%s: fmi2SerializeFMUstate: buffer of %zu bytes is too small", m->name, size);
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
    pf_log(m, fmi2Error, "logStatusError", "%s: fmi2DeSerializeFMUstate: %zu bytes are not a state of this FMU "
          "build", m->name, size);
    return fmi2Error;
  }
  s = (platform_state*) (*state ? *state : pf_alloc(m, 1, sizeof(platform_state)));
  if (!s) return fmi2Fatal;
  memcpy(s, bytes + sizeof SERIAL_MAGIC, sizeof(platform_state));
  *state = s;
  return fmi2OK;
}
