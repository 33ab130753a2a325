/* A mass on a spring and damper, or a pendulum, that starts wherever its start values put it: an
 * FMI 2.0 FMU (co-simulation and model exchange) for cosim's tests of the design model of an FMU
 * whose start is not an equilibrium (tests/test_fmu_equilibrium.py builds it with gcc against
 * FMPy's FMI headers).
 *
 *   der(x) = v,
 *   der(v) = (u + force - k x - k3 x^3 - c v) / m - g_l sin(x),   position = x.
 *
 * The parameters choose the plant: a linear mass-spring-damper (k > 0), a mass-damper without
 * spring (k = 0: every position is an equilibrium), a Duffing oscillator (k3), a pendulum (g_l = g/l,
 * x the angle), a free mass pushed by a constant force (k = 0, force != 0: no equilibrium).
 * Co-simulation integrates the same equations by classic Runge-Kutta, 100 steps per communication
 * step; model exchange leaves that to the importer. The directional derivatives are exact. With
 * x_max > 0, fmi2GetDerivatives fails where |x| > x_max, as a Modelica assert does.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

/* The start values of the states and the input (the modelDescription.xml's): compiled in. */
#ifndef X_START
#define X_START 0.0
#endif
#ifndef V_START
#define V_START 0.0
#endif
#ifndef U_START
#define U_START 0.0
#endif

enum { X, DER_X, V, DER_V, U, POSITION, M, K, K3, C, G_L, FORCE, X_MAX, N_REAL };

typedef struct {
    fmi2Real r[N_REAL];
    fmi2Real time;
    fmi2CallbackFunctions cb;
    fmi2String name;
} Model;

/* The FMI 2.0 calls both test FMUs answer alike (tests/data/fmus/common). */
#include "fmi2_unsupported.h"

static fmi2Real acceleration(const Model *m, fmi2Real x, fmi2Real v) {
    const fmi2Real *r = m->r;
    return (r[U] + r[FORCE] - r[K] * x - r[K3] * x * x * x - r[C] * v) / r[M] - r[G_L] * sin(x);
}

static fmi2Real value(const Model *m, fmi2ValueReference vr) {
    switch (vr) {
    case DER_X:
        return m->r[V];
    case DER_V:
        return acceleration(m, m->r[X], m->r[V]);
    case POSITION:
        return m->r[X];
    default:
        return m->r[vr];
    }
}

/* d(unknown)/d(known) at the current point. */
static fmi2Real partial(const Model *m, fmi2ValueReference unknown, fmi2ValueReference known) {
    const fmi2Real *r = m->r;
    if (unknown == DER_X && known == V) return 1.0;
    if (unknown == POSITION && known == X) return 1.0;
    if (unknown != DER_V) return 0.0;
    if (known == X) return (-r[K] - 3.0 * r[K3] * r[X] * r[X]) / r[M] - r[G_L] * cos(r[X]);
    if (known == V) return -r[C] / r[M];
    if (known == U) return 1.0 / r[M];
    return 0.0;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Model *m = calloc(1, sizeof(Model));
    m->cb = *cb;
    m->name = name;
    m->r[X] = X_START;
    m->r[V] = V_START;
    m->r[U] = U_START;
    m->r[M] = 1.0;
    m->r[K] = 4.0;
    m->r[C] = 0.4;
    return m;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    for (size_t j = 0; j < n; j++) v[j] = value(c, vr[j]);
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) { return fmi2Error; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) { return fmi2Error; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) { return fmi2Error; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return fmi2Error; }

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[], size_t nu,
                                        const fmi2ValueReference known[], size_t nk, const fmi2Real dk[], fmi2Real du[]) {
    for (size_t a = 0; a < nu; a++) {
        du[a] = 0.0;
        for (size_t b = 0; b < nk; b++) du[a] += partial(c, unknown[a], known[b]) * dk[b];
    }
    return fmi2OK;
}

/* Co-simulation: classic Runge-Kutta, 100 steps per communication step. */
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSet) {
    Model *m = c;
    const int steps = 100;
    fmi2Real s = h / steps, x = m->r[X], v = m->r[V];
    for (int j = 0; j < steps; j++) {
        fmi2Real k1x = v, k1v = acceleration(m, x, v);
        fmi2Real k2x = v + s / 2 * k1v, k2v = acceleration(m, x + s / 2 * k1x, v + s / 2 * k1v);
        fmi2Real k3x = v + s / 2 * k2v, k3v = acceleration(m, x + s / 2 * k2x, v + s / 2 * k2v);
        fmi2Real k4x = v + s * k3v, k4v = acceleration(m, x + s * k3x, v + s * k3v);
        x += s / 6 * (k1x + 2 * k2x + 2 * k3x + k4x);
        v += s / 6 * (k1v + 2 * k2v + 2 * k3v + k4v);
    }
    m->r[X] = x;
    m->r[V] = v;
    m->time = t + h;
    return fmi2OK;
}

/* Model exchange */
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    memset(e, 0, sizeof *e);
    return fmi2OK;
}
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSet, fmi2Boolean *event, fmi2Boolean *stop) {
    *event = fmi2False;
    *stop = fmi2False;
    return fmi2OK;
}
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) {
    ((Model *)c)->r[X] = x[0];
    ((Model *)c)->r[V] = x[1];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    Model *m = c;
    if (m->r[X_MAX] > 0 && fabs(m->r[X]) > m->r[X_MAX]) {
        if (m->cb.logger) m->cb.logger(m->cb.componentEnvironment, m->name, fmi2Error, "logStatusError", "x out of range");
        return fmi2Error;
    }
    dx[0] = m->r[V];
    dx[1] = acceleration(m, m->r[X], m->r[V]);
    return fmi2OK;
}
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = ((Model *)c)->r[X];
    x[1] = ((Model *)c)->r[V];
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) {
    x[0] = 1.0;
    x[1] = 1.0;
    return fmi2OK;
}
