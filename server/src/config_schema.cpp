#include "tendril/server/config_schema.hpp"

#include <algorithm>
#include <cmath>
#include <regex>
#include <set>
#include <stdexcept>
#include <vector>

#include "schema_files.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::set<std::string>& known_keywords() {
  static const std::set<std::string> keywords = {"type",
                                                 "properties",
                                                 "patternProperties",
                                                 "additionalProperties",
                                                 "required",
                                                 "items",
                                                 "minItems",
                                                 "maxItems",
                                                 "enum",
                                                 "const",
                                                 "minimum",
                                                 "maximum",
                                                 "exclusiveMinimum",
                                                 "exclusiveMaximum",
                                                 "minLength",
                                                 "maxLength",
                                                 "pattern",
                                                 "anyOf",
                                                 "oneOf",
                                                 "$ref",
                                                 "$defs",
                                                 "title",
                                                 "description",
                                                 "default",
                                                 "examples",
                                                 "$schema",
                                                 "$id",
                                                 "$comment"};
  return keywords;
}

std::string join_path(const std::string& path, const std::string& key) {
  return path.empty() ? key : path + "." + key;
}

std::string shown(const json& value) {
  std::string text = value.dump();
  if (text.size() > 60) text = text.substr(0, 57) + "...";
  return text;
}

// Levenshtein distance, for "did you mean".
std::size_t distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diagonal = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

bool type_matches(const std::string& type, const json& value) {
  if (type == "object") return value.is_object();
  if (type == "array") return value.is_array();
  if (type == "string") return value.is_string();
  if (type == "boolean") return value.is_boolean();
  if (type == "null") return value.is_null();
  if (type == "integer")
    return value.is_number_integer() || (value.is_number_float() && std::isfinite(value.get<double>()) &&
                                         std::floor(value.get<double>()) == value.get<double>());
  if (type == "number") return value.is_number() && std::isfinite(value.get<double>());
  return false;
}

std::string type_words(const json& type) {
  auto one = [](const std::string& t) {
    if (t == "object") return std::string("an object");
    if (t == "array") return std::string("an array");
    if (t == "integer") return std::string("an integer");
    if (t == "boolean") return std::string("true or false");
    if (t == "null") return std::string("null");
    if (t == "number") return std::string("a finite number");  // NaN and infinities never pass
    return "a " + t;
  };
  if (type.is_string()) return one(type.get<std::string>());
  std::string out;
  for (std::size_t i = 0; i < type.size(); ++i) {
    if (i > 0) out += i + 1 == type.size() ? " or " : ", ";
    out += one(type[i].get<std::string>());
  }
  return out;
}

class Validator {
 public:
  explicit Validator(const json& root) : root_(root) {}

  std::optional<std::string> check(const json& schema, const json& value, const std::string& path) const {
    const json& s = resolve(schema);
    if (s.is_boolean()) {
      if (s.get<bool>()) return std::nullopt;
      return where(path) + ": not allowed here";
    }
    if (const auto it = s.find("type"); it != s.end()) {
      bool any = false;
      if (it->is_string()) {
        any = type_matches(it->get<std::string>(), value);
      } else {
        for (const auto& t : *it) any = any || type_matches(t.get<std::string>(), value);
      }
      if (!any) return fail(path, type_words(*it), value);
    }
    if (const auto it = s.find("const"); it != s.end() && *it != value) return fail(path, shown(*it), value);
    if (const auto it = s.find("enum"); it != s.end()) {
      if (std::find(it->begin(), it->end(), value) == it->end()) {
        std::string options;
        for (const auto& option : *it) options += (options.empty() ? "" : ", ") + option.dump();
        return fail(path, "one of " + options, value);
      }
    }
    if (value.is_number()) {
      const double v = value.get<double>();
      if (const auto it = s.find("minimum"); it != s.end() && !(v >= it->get<double>()))
        return fail(path, "a number of at least " + it->dump(), value);
      if (const auto it = s.find("maximum"); it != s.end() && !(v <= it->get<double>()))
        return fail(path, "a number of at most " + it->dump(), value);
      if (const auto it = s.find("exclusiveMinimum"); it != s.end() && !(v > it->get<double>()))
        return fail(path, "a number greater than " + it->dump(), value);
      if (const auto it = s.find("exclusiveMaximum"); it != s.end() && !(v < it->get<double>()))
        return fail(path, "a number less than " + it->dump(), value);
    }
    if (value.is_string()) {
      const auto& text = value.get_ref<const std::string&>();
      if (const auto it = s.find("minLength"); it != s.end() && text.size() < it->get<std::size_t>())
        return fail(path, "a string of at least " + it->dump() + " characters", value);
      if (const auto it = s.find("maxLength"); it != s.end() && text.size() > it->get<std::size_t>())
        return fail(path, "a string of at most " + it->dump() + " characters", value);
      if (const auto it = s.find("pattern");
          it != s.end() && !std::regex_search(text, std::regex(it->get<std::string>())))
        return fail(path, "a string matching " + it->get<std::string>(), value);
    }
    if (value.is_array()) {
      if (const auto it = s.find("minItems"); it != s.end() && value.size() < it->get<std::size_t>())
        return fail(path, "an array of at least " + it->dump() + " items", value);
      if (const auto it = s.find("maxItems"); it != s.end() && value.size() > it->get<std::size_t>())
        return fail(path, "an array of at most " + it->dump() + " items", value);
      if (const auto it = s.find("items"); it != s.end()) {
        for (std::size_t i = 0; i < value.size(); ++i)
          if (auto e = check(*it, value[i], path + "[" + std::to_string(i) + "]")) return e;
      }
    }
    if (value.is_object()) {
      if (auto e = check_object(s, value, path)) return e;
    }
    if (const auto it = s.find("anyOf"); it != s.end()) {
      std::optional<std::string> first;
      for (const auto& option : *it) {
        auto e = check(option, value, path);
        if (!e) return std::nullopt;
        if (!first) first = e;
      }
      return first;
    }
    if (const auto it = s.find("oneOf"); it != s.end()) {
      int matches = 0;
      std::optional<std::string> first;
      for (const auto& option : *it) {
        auto e = check(option, value, path);
        if (!e) {
          ++matches;
        } else if (!first) {
          first = e;
        }
      }
      if (matches == 1) return std::nullopt;
      if (matches > 1) return where(path) + ": matches more than one of the allowed forms";
      return first;
    }
    return std::nullopt;
  }

 private:
  const json& resolve(const json& schema) const {
    const json* s = &schema;
    for (int depth = 0; depth < 16 && s->is_object() && s->contains("$ref"); ++depth) {
      const auto ref = (*s)["$ref"].get<std::string>();
      if (ref.rfind("#/$defs/", 0) != 0)
        throw std::invalid_argument("schema: only local $ref \"#/$defs/...\"");
      s = &root_.at("$defs").at(ref.substr(8));
    }
    return *s;
  }

  static std::string where(const std::string& path) { return path.empty() ? std::string("top level") : path; }

  static std::optional<std::string> fail(const std::string& path, const std::string& expected,
                                         const json& got) {
    return where(path) + ": expected " + expected + ", got " + shown(got);
  }

  std::optional<std::string> check_object(const json& s, const json& value, const std::string& path) const {
    const json empty = json::object();
    const json& properties = s.contains("properties") ? s["properties"] : empty;
    if (const auto it = s.find("required"); it != s.end()) {
      for (const auto& key : *it) {
        if (!value.contains(key.get<std::string>()))
          return join_path(path, key.get<std::string>()) + ": missing (this key is required)";
      }
    }
    for (const auto& [key, item] : value.items()) {
      const std::string at = join_path(path, key);
      if (const auto p = properties.find(key); p != properties.end()) {
        if (auto e = check(*p, item, at)) return e;
        continue;
      }
      bool matched = false;
      if (const auto pp = s.find("patternProperties"); pp != s.end()) {
        for (const auto& [pattern, sub] : pp->items()) {
          if (!std::regex_search(key, std::regex(pattern))) continue;
          matched = true;
          if (auto e = check(sub, item, at)) return e;
        }
      }
      if (matched) continue;
      if (const auto extra = s.find("additionalProperties"); extra != s.end()) {
        if (extra->is_boolean() && !extra->get<bool>()) return unknown_key(properties, key, at);
        if (auto e = check(*extra, item, at)) return e;
      }
    }
    return std::nullopt;
  }

  static std::string unknown_key(const json& properties, const std::string& key, const std::string& at) {
    std::string known;
    std::string closest;
    std::size_t best = 3;  // at most 2 edits count as a misspelling
    for (const auto& [name, sub] : properties.items()) {
      known += (known.empty() ? "" : ", ") + name;
      const auto d = distance(key, name);
      if (d < best) {
        best = d;
        closest = name;
      }
    }
    std::string message = at + ": unknown key";
    if (!known.empty()) message += " (expected one of " + known;
    if (!closest.empty()) message += "; did you mean " + closest + "?";
    if (!known.empty()) message += ")";
    return message;
  }

  const json& root_;
};

// "where/a/b": the place of a sub-schema in messages.
std::string schema_path(const std::string& where, const std::string& a, const std::string& b = {}) {
  std::string out = where;
  out += '/';
  out += a;
  if (!b.empty()) {
    out += '/';
    out += b;
  }
  return out;
}

void check_keywords(const json& schema, const std::string& where) {
  if (schema.is_boolean()) return;
  auto bad = [&where](const std::string& what) {
    std::string message = "schema at ";
    message += where;
    message += ": ";
    message += what;
    return std::invalid_argument(message);
  };
  if (!schema.is_object()) throw bad("not an object or a boolean");
  for (const auto& [key, value] : schema.items()) {
    if (!known_keywords().count(key)) throw bad("keyword \"" + key + "\" is not supported");
    if (key == "properties" || key == "patternProperties" || key == "$defs") {
      for (const auto& [name, sub] : value.items()) check_keywords(sub, schema_path(where, key, name));
    } else if (key == "items" || key == "additionalProperties") {
      check_keywords(value, schema_path(where, key));
    } else if (key == "anyOf" || key == "oneOf") {
      for (std::size_t i = 0; i < value.size(); ++i)
        check_keywords(value[i], schema_path(where, key, std::to_string(i)));
    } else if (key == "pattern") {
      (void)std::regex(value.get<std::string>());  // throws on a bad pattern
    }
  }
}

json parse_embedded(const char* text, const char* name) {
  json schema = json::parse(text);
  check_keywords(schema, name);
  return schema;
}

}  // namespace

std::optional<std::string> schema_violation(const json& schema, const json& value) {
  return Validator(schema).check(schema, value, "");
}

void check_schema(const json& schema) { check_keywords(schema, "#"); }

json robot_schema(const json& type_settings_schema, const std::string& kind) {
  json schema = core_robot_schema();
  schema["properties"]["kind"] = {{"const", kind}};
  if (type_settings_schema.contains("properties")) {
    for (const auto& [key, sub] : type_settings_schema["properties"].items()) schema["properties"][key] = sub;
  }
  if (type_settings_schema.contains("required")) {
    for (const auto& key : type_settings_schema["required"]) schema["required"].push_back(key);
  }
  if (type_settings_schema.contains("$defs")) {
    for (const auto& [key, sub] : type_settings_schema["$defs"].items()) schema["$defs"][key] = sub;
  }
  if (type_settings_schema.contains("title")) schema["title"] = type_settings_schema["title"];
  check_schema(schema);
  return schema;
}

const json& server_file_schema() {
  static const json schema = parse_embedded(schema_files::kServer, "config/schemas/server.schema.json");
  return schema;
}

const json& core_robot_schema() {
  static const json schema = parse_embedded(schema_files::kRobot, "config/schemas/robot.schema.json");
  return schema;
}

}  // namespace tendril::server
