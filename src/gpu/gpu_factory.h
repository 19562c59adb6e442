// Entry points to the GPU backend that link in every build (gpu_factory.cpp is compiled with or without CUDA):
// without CUDA, gpuAvailable() is false and makeGpuSystem() throws InputError, so the CLI and the C++ API need no
// #ifdef (`--backend gpu` on a machine without a device fails with a clear message; `--backend auto` picks the
// CPU). The core does not include this file: the drop-in world takes these functions through DviWorldConfig.
#pragma once

#include <memory>
#include <string>

#include "chrono_like/system.h"

namespace dvi {

// True when this build has the CUDA backend and a device is usable. *name gets the device name, or the
// reason there is none.
bool gpuAvailable(std::string* name = nullptr);

// The GPU system (src/gpu/gpu_system.h). Throws InputError when the build has no CUDA backend or no
// device is present. bullet_collision: as for System.
std::unique_ptr<System> makeGpuSystem(const SystemConfig& config, CollisionFactory bullet_collision = nullptr);

// One GPU a process (a domain decomposition over MPI): makes device index % (the devices this process sees) the
// current one, before the first GPU System; returns its index, or -1 where there is none (or no CUDA backend).
int selectGpu(int index);

}  // namespace dvi
