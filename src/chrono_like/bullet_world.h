// Deprecated include path, kept for one release: the Bullet drop-in world was included as
// "chrono_like/bullet_world.h" before the engine's folders were regrouped. Include <dvisim/bullet_world.h>, the
// public path that stays when the internals move (docs/INSTALL.md, "Public headers").
#pragma once

#pragma message("dvisim: \"chrono_like/bullet_world.h\" is deprecated; include <dvisim/bullet_world.h>")
#include "dvisim/bullet_world.h"
