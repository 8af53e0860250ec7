#include "tendril/teleop/strict_json.hpp"

#include <memory>
#include <type_traits>
#include <unordered_set>
#include <utility>
#include <vector>

namespace tendril::teleop {

namespace {

using Json = nlohmann::json;

// SAX handler: nlohmann's own DOM builder does the building; this adds the depth limit and the
// duplicate-key rule. Every event is O(1) (amortised), unlike the callback parser's end_object.
class StrictDomBuilder {
 public:
  using number_integer_t = Json::number_integer_t;
  using number_unsigned_t = Json::number_unsigned_t;
  using number_float_t = Json::number_float_t;
  using string_t = Json::string_t;
  using binary_t = Json::binary_t;

  StrictDomBuilder(Json& root, int max_depth, StrictJson& result)
      : dom_(root, /*allow_exceptions=*/false), max_depth_(max_depth), result_(result) {}

  bool null() { return dom_.null(); }
  bool boolean(bool value) { return dom_.boolean(value); }
  bool number_integer(number_integer_t value) { return dom_.number_integer(value); }
  bool number_unsigned(number_unsigned_t value) { return dom_.number_unsigned(value); }
  bool number_float(number_float_t value, const string_t& text) { return dom_.number_float(value, text); }
  bool string(string_t& value) { return dom_.string(value); }
  bool binary(binary_t& value) { return dom_.binary(value); }

  bool start_object(std::size_t length) {
    if (!enter()) return false;
    open_objects_.push_back(OpenObject{keys_.size(), nullptr});
    return dom_.start_object(length);
  }

  bool key(string_t& key) {
    if (!open_objects_.empty() && !remember_key(open_objects_.back(), key) &&
        result_.error == StrictJsonError::kNone && result_.duplicate_key.empty()) {
      // Parsing goes on: a syntax error later in the text is the error to report.
      result_.duplicate_key = key;
    }
    return dom_.key(key);
  }

  bool end_object() {
    if (!open_objects_.empty()) {
      keys_.resize(open_objects_.back().first_key);
      open_objects_.pop_back();
    }
    --depth_;
    return dom_.end_object();
  }

  bool start_array(std::size_t length) { return enter() && dom_.start_array(length); }

  bool end_array() {
    --depth_;
    return dom_.end_array();
  }

  template <class Exception>
  bool parse_error(std::size_t position, const std::string& last_token, const Exception& exception) {
    if constexpr (std::is_same_v<Exception, Json::parse_error>) {
      result_.error = StrictJsonError::kSyntax;
      result_.byte = exception.byte;
    } else {
      // out_of_range 406: a number too large for a double (found once by fuzz_rest_body).
      result_.error = StrictJsonError::kNumberOutOfRange;
      result_.byte = position;
    }
    result_.parser_message = exception.what();
    return dom_.parse_error(position, last_token, exception);
  }

 private:
  // Up to this many keys an object's keys are compared one by one; beyond, they go into a hash set,
  // so an object with many keys stays linear and the common small object allocates no set.
  static constexpr std::size_t kKeysScannedLinearly = 16;

  struct OpenObject {
    std::size_t first_key;  // index into keys_ of this object's first key
    std::unique_ptr<std::unordered_set<std::string>> many_keys;
  };

  bool enter() {
    if (++depth_ <= max_depth_) return true;
    result_.error = StrictJsonError::kTooDeep;
    return false;
  }

  // False when `key` was already given in `object`.
  bool remember_key(OpenObject& object, const std::string& key) {
    if (object.many_keys) return object.many_keys->insert(key).second;
    for (std::size_t i = object.first_key; i < keys_.size(); ++i) {
      if (keys_[i] == key) return false;
    }
    if (keys_.size() - object.first_key < kKeysScannedLinearly) {
      keys_.push_back(key);
      return true;
    }
    object.many_keys = std::make_unique<std::unordered_set<std::string>>(
        std::make_move_iterator(keys_.begin() + static_cast<std::ptrdiff_t>(object.first_key)),
        std::make_move_iterator(keys_.end()));
    keys_.resize(object.first_key);
    return object.many_keys->insert(key).second;
  }

  nlohmann::detail::json_sax_dom_parser<Json> dom_;
  int max_depth_;
  int depth_ = 0;
  StrictJson& result_;
  std::vector<OpenObject> open_objects_;  // innermost last
  std::vector<std::string> keys_;         // keys of the open objects still scanned linearly
};

}  // namespace

StrictJson parse_strict_json(std::string_view text, int max_depth) {
  StrictJson result;
  StrictDomBuilder builder(result.value, max_depth, result);
  const bool parsed = Json::sax_parse(text.begin(), text.end(), &builder);
  if (parsed && result.error == StrictJsonError::kNone && !result.duplicate_key.empty()) {
    result.error = StrictJsonError::kDuplicateKey;
  } else if (!parsed && result.error == StrictJsonError::kNone) {
    result.error = StrictJsonError::kSyntax;  // not expected: every refusal above sets its reason
  }
  if (result.error != StrictJsonError::kDuplicateKey) result.duplicate_key.clear();
  if (!result.ok()) result.value = Json(Json::value_t::discarded);
  return result;
}

}  // namespace tendril::teleop
