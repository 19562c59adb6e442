// The deprecated include paths of the Bullet drop-in world, kept for one release (docs/INSTALL.md): a program
// written against them still compiles (the older one with a deprecation message).
#include "chrono_like/bullet/bullet_world.h"
#include "chrono_like/bullet_world.h"

bool deprecatedPathsCompile() { return sizeof(dvi::DviDynamicsWorld) > 0; }
