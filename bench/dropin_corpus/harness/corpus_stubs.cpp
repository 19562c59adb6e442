// Definitions the examples link against that live in Bullet's example browser, not in Bullet's libraries: the
// resource-path lookup (RollingFrictionDemo calls it only to save a .bullet file when asked, which a headless run
// never is) and a silent b3Printf (TestHingeTorque prints its joint feedback every 16 frames).
#include <Bullet3Common/b3Logging.h>

#include "Utils/b3ResourcePath.h"

int b3ResourcePath::findResourcePath(const char*, char*, int, PFN_FIND_FILE, void*) { return 0; }

namespace corpus {
void silencePrintf() {
  b3SetCustomPrintfFunc([](const char*) {});
}
}  // namespace corpus
