// dvisim's public face: the Bullet drop-in world (dvi::DviDynamicsWorld, dvi::DviWorldConfig; docs/DROP_IN.md).
// Include <dvisim/bullet_world.h>; this path stays when the engine's internal folders move (docs/INSTALL.md).
#pragma once

#include "chrono_like/bullet/bullet_world.h"
