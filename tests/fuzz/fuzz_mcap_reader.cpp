// Fuzz target: MCAP files given to tendrild --replay (outside input), through McapReader (summary or
// streaming) and every message through McapMessageCursor. Bad input must end in McapFormatError with a
// message, never a crash, a hang or a message out of log-time order.
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include "tendril/record/mcap_reader.hpp"

using namespace tendril::record;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  McapReaderOptions options;
  options.max_chunk_bytes = 1 << 20;  // keeps each run small; the limit's own path is exercised too
  try {
    const McapReader reader(std::vector<std::uint8_t>(data, data + size), "fuzz", options);
    McapMessageCursor cursor({&reader});
    McapMessageCursor::Item item;
    std::uint64_t previous = 0, count = 0;
    while (cursor.next(item)) {
      if (item.message.log_time < previous || item.channel == nullptr) std::abort();
      if (item.channel->id != item.message.channel_id) std::abort();
      previous = item.message.log_time;
      ++count;
    }
  } catch (const McapFormatError& e) {
    if (std::string_view(e.what()).empty()) std::abort();
  }
  return 0;
}
