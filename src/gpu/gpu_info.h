// Device discovery for the GPU backend (CUDA builds only; the always-linked entry points are in
// gpu/gpu_factory.h).
#pragma once

#include <string>

namespace dvi::gpu {

// True when a CUDA device can be used; its name (and memory) go to *name when given.
bool queryDevice(std::string* name);
// Makes device index % (the device count) this process's current device; returns it, or -1 without a device.
int selectDevice(int index);

}  // namespace dvi::gpu
