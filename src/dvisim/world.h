// dvisim's public face: the DVI system (dvi::System, dvi::SystemConfig, dvi::BodyDesc, the shape makers).
// Include <dvisim/world.h>; this path stays when the engine's internal folders move (docs/INSTALL.md).
#pragma once

#include "chrono_like/system.h"
