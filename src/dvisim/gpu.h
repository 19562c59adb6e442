// dvisim's public face: the GPU backend's entry points (dvi::gpuAvailable, dvi::makeGpuSystem, dvi::selectGpu),
// present in every build (without CUDA, gpuAvailable() is false). Include <dvisim/gpu.h>; this path stays when
// the engine's internal folders move (docs/INSTALL.md).
#pragma once

#include "gpu/gpu_factory.h"
