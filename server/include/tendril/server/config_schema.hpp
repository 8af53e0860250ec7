// Configuration files are checked against JSON Schemas (config/schemas/) before they are read, so a
// misspelled or unknown key is refused with the file, the key and what was expected, instead of being
// ignored. The validator implements the subset of JSON Schema 2020-12 the schemas use: type,
// properties, patternProperties, additionalProperties, required, items, minItems, maxItems, enum,
// const, minimum, maximum, exclusiveMinimum, exclusiveMaximum, minLength, maxLength, pattern, anyOf,
// oneOf and local $ref ("#/$defs/..."). Annotation keywords (title, description, default, examples,
// $schema, $id, $comment) are ignored; any other keyword is refused when the schema is loaded.
#pragma once

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

namespace tendril::server {

// The first place where `value` breaks `schema`: "catheter.spring_deflection.limt_mm: unknown key
// (expected one of node_id, volts_per_mm, limit_mm, stale_ms; did you mean limit_mm?)". Empty path
// segments are written as "top level". nullopt when the value conforms.
std::optional<std::string> schema_violation(const nlohmann::json& schema, const nlohmann::json& value);

// Throws std::invalid_argument when `schema` uses a keyword outside the subset above (a typo in a
// schema must not silently accept everything).
void check_schema(const nlohmann::json& schema);

// The core robot-file schema with a robot type's own sections merged in: its "properties" (and
// "required") are added to the top level.
nlohmann::json robot_schema(const nlohmann::json& type_settings_schema, const std::string& kind);

// The server file's schema and the core robot file's schema (config/schemas/, compiled in).
const nlohmann::json& server_file_schema();
const nlohmann::json& core_robot_schema();

}  // namespace tendril::server
