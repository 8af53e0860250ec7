// Build version of tendril, reported by /api/v1/health and tendrild --version.
#pragma once

namespace tendril::server {
const char* version() noexcept;
}
