// dvisim's public face: Bullet bodies into a dvi::System and back (dvi::importBullet, dvi::writeBackToBullet).
// Include <dvisim/bullet_import.h>; this path stays when the engine's internal folders move (docs/INSTALL.md).
#pragma once

#include "chrono_like/bullet/bullet_import.h"
