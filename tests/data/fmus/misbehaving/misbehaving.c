/* A small FMI 2.0 FMU (co-simulation and model exchange) that misbehaves on request, for cosim's
 * tests of FMU plants (tests/test_fmu_failures.py builds it with gcc against FMPy's FMI headers).
 *
 *   der(x) = -k x + u,   y = gain x (computed only where OpenModelica's FMUs compute their
 *   outputs: at initialization, events, fmi2CompletedIntegratorStep and fmi2DoStep; stale after
 *   fmi2SetContinuousStates), u_seen = u, gear_seen = gear, on_seen = on, count_seen = count.
 *
 * The parameter `mode` chooses the misbehaviour, from t >= `trigger` on (in fmi2DoStep, or in
 * fmi2GetDerivatives for model exchange): 0 none, 1 loop forever, 2 segfault, 3 return fmi2Error
 * (after logging why), 4 return fmi2Fatal, 5 print to stdout and log a warning at every step,
 * 6 a NaN derivative (the solver fails), 7 wrong directional derivatives (twice the true ones).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

enum { X, DER_X, U, Y, U_SEEN, K, GAIN, TRIGGER, N_REAL };
enum { MODE, GEAR, COUNT, GEAR_SEEN, COUNT_SEEN, N_INT };
enum { ON, ON_SEEN, N_BOOL };

typedef struct {
    fmi2Real r[N_REAL];
    fmi2Integer i[N_INT];
    fmi2Boolean b[N_BOOL];
    fmi2Real time;
    fmi2CallbackFunctions cb;
    fmi2String name;
} Model;

/* The FMI 2.0 calls both test FMUs answer alike (tests/data/fmus/common). */
#include "fmi2_unsupported.h"

static void say(Model *m, fmi2Status status, const char *category, const char *message) {
    if (m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, status, category, message);
}

static void outputs(Model *m) {
    m->r[Y] = m->r[GAIN] * m->r[X];
    m->r[U_SEEN] = m->r[U];
    m->i[GEAR_SEEN] = m->i[GEAR];
    m->i[COUNT_SEEN] = m->i[COUNT];
    m->b[ON_SEEN] = m->b[ON];
}

static fmi2Real derivative(Model *m) { return -m->r[K] * m->r[X] + m->r[U]; }

/* The misbehaviour of `mode` at the current time, where `where` is the call. */
static fmi2Status misbehave(Model *m, const char *where) {
    char text[200];
    if (m->time < m->r[TRIGGER] - 1e-12) return fmi2OK;
    switch (m->i[MODE]) {
    case 1: {
        volatile int spin = 1;
        while (spin) {
        }
        return fmi2OK;
    }
    case 2:
        *(volatile int *)0 = 1;
        return fmi2OK;
    case 3:
        snprintf(text, sizeof text, "the plant broke at t = %g in %s", m->time, where);
        say(m, fmi2Error, "logStatusError", text);
        return fmi2Error;
    case 4:
        say(m, fmi2Fatal, "logStatusFatal", "out of memory (on purpose)");
        return fmi2Fatal;
    case 5:
        printf("%s at t = %g\n", where, m->time);
        say(m, fmi2Warning, "logStatusWarning", "a chatty step");
        return fmi2OK;
    default:
        return fmi2OK;
    }
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Model *m = calloc(1, sizeof(Model));
    m->cb = *cb;
    m->name = name;
    m->r[X] = 1.0;
    m->r[U] = 0.5;
    m->r[K] = 1.0;
    m->r[GAIN] = 2e5;
    m->r[TRIGGER] = 0.5;
    m->i[GEAR] = 2;
    m->i[COUNT] = 7;
    m->b[ON] = fmi2True;
    return m;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    outputs(c);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Model *m = c;
    for (size_t j = 0; j < n; j++) v[j] = vr[j] == DER_X ? derivative(m) : m->r[vr[j]];
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    for (size_t j = 0; j < n; j++) v[j] = ((Model *)c)->i[vr[j]];
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    for (size_t j = 0; j < n; j++) v[j] = ((Model *)c)->b[vr[j]];
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) {
    Model *m = c;
    for (size_t j = 0; j < n; j++) {
        if (vr[j] == GEAR && (v[j] < 1 || v[j] > 3)) {
            say(m, fmi2Error, "logStatusError", "gear must be 1, 2 or 3");
            return fmi2Error;
        }
        m->i[vr[j]] = v[j];
    }
    return fmi2OK;
}
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) {
    for (size_t j = 0; j < n; j++) ((Model *)c)->b[vr[j]] = v[j];
    return fmi2OK;
}

/* d(der_x)/dx = -k, d(der_x)/du = 1, dy/dx = gain, d(u_seen)/du = 1 (twice these with mode 7). */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[], size_t nu,
                                        const fmi2ValueReference known[], size_t nk, const fmi2Real dk[], fmi2Real du[]) {
    Model *m = c;
    fmi2Real wrong = m->i[MODE] == 7 ? 2.0 : 1.0;
    for (size_t a = 0; a < nu; a++) {
        du[a] = 0.0;
        for (size_t b = 0; b < nk; b++) {
            fmi2Real d = 0.0;
            if (unknown[a] == DER_X && known[b] == X) d = -m->r[K];
            if (unknown[a] == DER_X && known[b] == U) d = 1.0;
            if (unknown[a] == Y && known[b] == X) d = m->r[GAIN];
            if (unknown[a] == U_SEEN && known[b] == U) d = 1.0;
            du[a] += wrong * d * dk[b];
        }
    }
    return fmi2OK;
}

/* Co-simulation */
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Model *m = c;
    m->time = t;
    fmi2Status status = misbehave(m, "fmi2DoStep");
    if (status > fmi2Warning) return status;
    for (int j = 0; j < 10; j++) m->r[X] += h / 10 * derivative(m);
    m->time = t + h;
    outputs(m);
    return fmi2OK;
}

/* Model exchange */
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    memset(e, 0, sizeof *e);
    outputs(c);
    return fmi2OK;
}
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet, fmi2Boolean *event, fmi2Boolean *stop) {
    *event = fmi2False;
    *stop = fmi2False;
    outputs(c);
    return fmi2OK;
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    ((Model *)c)->r[X] = x[0];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Model *m = c;
    fmi2Status status = misbehave(m, "fmi2GetDerivatives");
    if (status > fmi2Warning) return status;
    dx[0] = m->i[MODE] == 6 && m->time >= m->r[TRIGGER] ? NAN : derivative(m);
    return fmi2OK;
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = ((Model *)c)->r[X];
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = 1.0;
    return fmi2OK;
}
