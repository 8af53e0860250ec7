#include "tendril/server/version.hpp"

namespace tendril::server {
const char* version() noexcept { return TENDRIL_VERSION; }
}  // namespace tendril::server
