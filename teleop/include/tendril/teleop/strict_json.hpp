// One JSON parser for every text a client sends (REST bodies, Foxglove client messages, segmentation
// parameters): nlohmann's parser, plus two rules it does not have, checked in the same single pass.
//  - An object with the same key twice is refused: RFC 8259 leaves its meaning open and nlohmann keeps
//    the last value, so a check that read one copy and an action that read another could disagree
//    ({"mode":[],"mode":"x"}).
//  - Nesting deeper than a limit is refused as soon as it is reached, so hostile text cannot make the
//    parser's stacks grow.
// It runs in time linear in the text: nlohmann's callback parser, used before for the duplicate rule,
// scans the parent container after every closing '}' (64 KiB of small objects took 1.8 s).
//
// It lives in tendril::teleop because that is the lowest library both the HTTP front end (through
// tendril::safety) and tendril::perception link; it depends on nothing else of teleop.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

namespace tendril::teleop {

enum class StrictJsonError {
  kNone,
  kSyntax,            // not JSON; `byte` says where
  kNumberOutOfRange,  // a number too large for a double (1e999)
  kTooDeep,           // arrays/objects nested deeper than the limit
  kDuplicateKey,      // an object has `duplicate_key` twice
};

struct StrictJson {
  nlohmann::json value;  // the parsed text; discarded unless error == kNone
  StrictJsonError error = StrictJsonError::kNone;
  // kSyntax, kNumberOutOfRange: characters read when the parser stopped (nlohmann's parse_error::byte).
  std::size_t byte = 0;
  std::string parser_message;  // kSyntax, kNumberOutOfRange: nlohmann's exception text
  std::string duplicate_key;   // kDuplicateKey: the key (unescaped)

  bool ok() const noexcept { return error == StrictJsonError::kNone; }
};

// Parses `text` as one JSON value (nothing but whitespace after it), refusing duplicate keys and
// nesting deeper than `max_depth` arrays/objects. When several faults are present, the first one met
// wins, except that a duplicate key is reported only if the rest of the text is valid JSON (so a
// truncated body reads as malformed rather than as a duplicate). Throws nothing but std::bad_alloc.
StrictJson parse_strict_json(std::string_view text, int max_depth);

}  // namespace tendril::teleop
