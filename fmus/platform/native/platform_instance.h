/* The instance of the native platform FMU, shared by the FMI layer (fmi2_platform.c) and the model
 * step (platform_model.c). */
#ifndef PLATFORM_INSTANCE_H
#define PLATFORM_INSTANCE_H

#include <stddef.h>

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

void pf_log(inst_t* m, fmi2Status status, const char* category, const char* fmt, ...);
/* Python's repr of a float into buf (32 bytes) */
const char* pf_repr(double x, char* buf);
void* pf_alloc(inst_t* m, size_t n, size_t size);
void pf_release(inst_t* m, void* p);
/* fmi2ExitInitializationMode: check the parameters, build the model, set the initial outputs */
fmi2Status platform_setup(inst_t* m);
/* one macro step from t to t + h (s), inputs already checked; fmi2Discard leaves the state as it was */
fmi2Status platform_step(inst_t* m, double t, double h);

#endif
