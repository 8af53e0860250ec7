// The JSON Schema subset the configuration files are checked with (config_schema.hpp), and the
// shipped schemas against the shipped files.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "tendril/server/config_schema.hpp"
#include "tendril/server/robot_types.hpp"

namespace tendril::server {
namespace {

using nlohmann::json;

const std::filesystem::path kSource = TENDRIL_SOURCE_DIR;

json read(const std::filesystem::path& file) {
  std::ifstream in(file);
  return json::parse(in);
}

TEST(ConfigSchema, UnknownKeysAreRefusedWithTheKeyAndWhatWasExpected) {
  const json schema = {
      {"type", "object"},
      {"additionalProperties", false},
      {"properties", {{"limit_mm", {{"type", "number"}}}, {"stale_ms", {{"type", "number"}}}}}};
  EXPECT_FALSE(schema_violation(schema, {{"limit_mm", 1.5}}));
  const auto why = schema_violation(schema, {{"limt_mm", 1.5}});
  ASSERT_TRUE(why);
  EXPECT_NE(why->find("limt_mm: unknown key"), std::string::npos) << *why;
  EXPECT_NE(why->find("expected one of limit_mm, stale_ms"), std::string::npos) << *why;
  EXPECT_NE(why->find("did you mean limit_mm?"), std::string::npos) << *why;
}

TEST(ConfigSchema, NestedPathsTypesRangesAndEnumsAreNamed) {
  const json schema = {{"type", "object"},
                       {"properties",
                        {{"joints",
                          {{"type", "array"},
                           {"items",
                            {{"type", "object"},
                             {"required", {"unit"}},
                             {"properties",
                              {{"unit", {{"enum", {"mm", "rad"}}}},
                               {"max_velocity", {{"type", "number"}, {"exclusiveMinimum", 0}}}}}}}}}}}};
  auto why = schema_violation(schema, {{"joints", {{{"unit", "inch"}}}}});
  ASSERT_TRUE(why);
  EXPECT_EQ(*why, "joints[0].unit: expected one of \"mm\", \"rad\", got \"inch\"");
  why = schema_violation(schema, {{"joints", {{{"unit", "mm"}, {"max_velocity", 0}}}}});
  ASSERT_TRUE(why);
  EXPECT_EQ(*why, "joints[0].max_velocity: expected a number greater than 0, got 0");
  why = schema_violation(schema, {{"joints", {json::object()}}});
  ASSERT_TRUE(why);
  EXPECT_EQ(*why, "joints[0].unit: missing (this key is required)");
  why = schema_violation(schema, {{"joints", "all"}});
  ASSERT_TRUE(why);
  EXPECT_EQ(*why, "joints: expected an array, got \"all\"");
}

TEST(ConfigSchema, RefsPatternsAndAlternatives) {
  const json schema = {{"$defs", {{"pair", {{"type", "array"}, {"minItems", 2}, {"maxItems", 2}}}}},
                       {"type", "object"},
                       {"additionalProperties", false},
                       {"patternProperties", {{"^(.*_)?note$", {{"type", "string"}}}}},
                       {"properties",
                        {{"gains", {{"$ref", "#/$defs/pair"}}},
                         {"vessel", {{"anyOf", {{{"type", "string"}}, {{"const", false}}}}}}}}};
  EXPECT_FALSE(schema_violation(schema, {{"gains", {1, 2}}, {"gain_note", "why"}, {"vessel", false}}));
  EXPECT_TRUE(schema_violation(schema, {{"gains", {1, 2, 3}}}));
  EXPECT_TRUE(schema_violation(schema, {{"gain_note", 3}}));
  EXPECT_TRUE(schema_violation(schema, {{"vessel", true}}));
}

TEST(ConfigSchema, AnUnsupportedKeywordInASchemaIsRefused) {
  EXPECT_THROW(check_schema({{"type", "object"}, {"propertees", json::object()}}), std::invalid_argument);
  EXPECT_NO_THROW(check_schema(core_robot_schema()));
  EXPECT_NO_THROW(check_schema(server_file_schema()));
}

TEST(ConfigSchema, TheShippedFilesConformToTheirSchemas) {
  EXPECT_FALSE(schema_violation(server_file_schema(), read(kSource / "config/server.json")));
  for (const auto& entry : std::filesystem::directory_iterator(kSource / "config/robots")) {
    const json file = read(entry.path());
    const auto* type = builtin_robot_types().find(file.value("kind", std::string()));
    ASSERT_NE(type, nullptr) << entry.path() << ": no robot type " << file.value("kind", std::string());
    const auto why = schema_violation(robot_schema(type->settings_schema(), type->kind()), file);
    EXPECT_FALSE(why) << entry.path() << ": " << *why;
  }
}

TEST(ConfigSchema, EveryRobotTypesSchemaIsWellFormed) {
  for (const auto& kind : builtin_robot_types().kinds()) {
    const auto* type = builtin_robot_types().find(kind);
    EXPECT_NO_THROW(check_schema(robot_schema(type->settings_schema(), kind))) << kind;
  }
}

}  // namespace
}  // namespace tendril::server
