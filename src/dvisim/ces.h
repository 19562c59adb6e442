// dvisim's public face: the corona electrostatic separator as a plug-in of a dvi::System (dvi::CesMachine,
// dvi::CesConfig; docs/CES.md). Include <dvisim/ces.h>; this path stays when the internal folders move.
#pragma once

#include "ces/ces_config.h"
#include "ces/machine.h"
