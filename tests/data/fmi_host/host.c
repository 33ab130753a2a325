/* A minimal FMI 3.0 co-simulation host in C, as a non-Python tool (Simulink, OMSimulator) loads an
   FMU: no Python in the process until the FMU's binary starts one. It instantiates, initializes,
   sets input VR_IN to 1 + 0.01 k before step k, and prints output VR_OUT after it, to 17 digits.
   Usage: host BINARY.so RESOURCES_DIR TOKEN VR_IN VR_OUT STEPS DT  (tests/test_fmu_export.py) */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include "fmi3Functions.h"

static void logger(fmi3InstanceEnvironment e, fmi3Status s, fmi3String c, fmi3String m) { fprintf(stderr, "[%d][%s] %s\n", s, c, m); }

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(lib, #name); if (!name) { fprintf(stderr, "no %s\n", #name); return 2; }

int main(int argc, char **argv) {
    void *lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) { fprintf(stderr, "dlopen: %s\n", dlerror()); return 1; }
    LOAD(fmi3InstantiateCoSimulation) LOAD(fmi3EnterInitializationMode) LOAD(fmi3ExitInitializationMode)
    LOAD(fmi3DoStep) LOAD(fmi3GetFloat64) LOAD(fmi3SetFloat64) LOAD(fmi3Terminate) LOAD(fmi3FreeInstance)
    fmi3Instance fmu = fmi3InstantiateCoSimulation("host", argv[3], argv[2], fmi3False, fmi3True, fmi3False, fmi3False, NULL, 0, NULL, logger, NULL);
    if (!fmu) { fprintf(stderr, "instantiate failed\n"); return 3; }
    double dt = atof(argv[7]);
    if (fmi3EnterInitializationMode(fmu, fmi3False, 0.0, 0.0, fmi3False, 0.0) > fmi3Warning) return 4;
    if (fmi3ExitInitializationMode(fmu) > fmi3Warning) return 5;
    fmi3ValueReference in = atoi(argv[4]), out = atoi(argv[5]);
    for (int k = 0; k < atoi(argv[6]); k++) {
        fmi3Float64 y = 1.0 + 0.01 * k, x;
        fmi3Boolean event, terminate, early; fmi3Float64 last;
        fmi3SetFloat64(fmu, &in, 1, &y, 1);
        if (fmi3DoStep(fmu, k * dt, dt, fmi3True, &event, &terminate, &early, &last) > fmi3Warning) return 6;
        fmi3GetFloat64(fmu, &out, 1, &x, 1);
        printf("%d %.17g\n", k, x);
        fflush(stdout);
    }
    fmi3Terminate(fmu);
    fmi3FreeInstance(fmu);
    dlclose(lib);
    fprintf(stderr, "closed\n"); /* every FMI call returned, the library is unloaded */
    return 0;
}
