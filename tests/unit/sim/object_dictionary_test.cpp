// ObjectDictionary: the table behind the simulated node's SDO server and PDO engine.
#include "tendril/drivers/sim/object_dictionary.hpp"

#include <gtest/gtest.h>

#include "tendril/drivers/canopen/protocol.hpp"

namespace tendril::sim {
namespace {

namespace abort_code = canopen::sdo_abort;

ObjectDictionary make() {
  ObjectDictionary od;
  od.add(0x6064, 0, OdType::i32, OdAccess::read_only, -5, true);
  od.add(0x1017, 0, OdType::u16, OdAccess::read_write, 0);
  od.add(0x6060, 0, OdType::i8, OdAccess::read_write, 8);
  od.add(0x2001, 0, OdType::u8, OdAccess::write_only, 0);
  od.add_string(0x1008, 0, OdAccess::constant, "name", 8);
  od.set_range(0x1017, 0, 0, 1000);
  od.freeze();
  return od;
}

TEST(ObjectDictionary, ReadsLittleEndianWithTheTypeSize) {
  auto od = make();
  std::uint8_t buf[8]{};
  std::size_t n = 0;
  ASSERT_EQ(od.read(0x6064, 0, buf, sizeof buf, n), 0u);
  EXPECT_EQ(n, 4u);
  EXPECT_EQ(buf[0], 0xFB);
  EXPECT_EQ(buf[3], 0xFF);
  ASSERT_EQ(od.read(0x1008, 0, buf, sizeof buf, n), 0u);
  EXPECT_EQ(std::string(reinterpret_cast<char*>(buf), n), "name");
}

TEST(ObjectDictionary, RefusesWithTheRightAbortCode) {
  auto od = make();
  std::uint8_t buf[8]{0x10, 0x27};
  std::size_t n = 0;
  EXPECT_EQ(od.read(0x1234, 0, buf, sizeof buf, n), abort_code::no_object);
  EXPECT_EQ(od.read(0x1017, 1, buf, sizeof buf, n), abort_code::no_subindex);
  EXPECT_EQ(od.read(0x2001, 0, buf, sizeof buf, n), abort_code::write_only);
  EXPECT_EQ(od.write(0x6064, 0, buf, 4), abort_code::read_only);
  EXPECT_EQ(od.write(0x1008, 0, buf, 2), abort_code::read_only);
  EXPECT_EQ(od.write(0x1017, 0, buf, 4), abort_code::length_mismatch);
  EXPECT_EQ(od.write(0x1017, 0, buf, 2), abort_code::value_range) << "10000 > 1000";
  std::uint8_t ok[2]{0xE8, 0x03};
  EXPECT_EQ(od.write(0x1017, 0, ok, 2), 0u);
  EXPECT_EQ(od.find(0x1017, 0)->value, 1000);
  std::uint8_t neg[1]{0xFD};
  EXPECT_EQ(od.write(0x6060, 0, neg, 1), 0u);
  EXPECT_EQ(od.find(0x6060, 0)->value, -3) << "signed types sign-extend";
}

TEST(ObjectDictionary, WriteCheckCanVeto) {
  ObjectDictionary od;
  od.add(0x6060, 0, OdType::i8, OdAccess::read_write, 8);
  od.set_write_check(
      [](std::uint16_t, std::uint8_t, std::int64_t v) { return v == 8 ? 0u : abort_code::value_range; });
  od.freeze();
  std::uint8_t v = 9;
  EXPECT_EQ(od.write(0x6060, 0, &v, 1), abort_code::value_range);
  v = 8;
  EXPECT_EQ(od.write(0x6060, 0, &v, 1), 0u);
}

TEST(ObjectDictionary, ResetRestoresDefaultsAndSetUpErrorsThrow) {
  auto od = make();
  std::uint8_t v[2]{5, 0};
  ASSERT_EQ(od.write(0x1017, 0, v, 2), 0u);
  od.reset_communication();
  EXPECT_EQ(od.find(0x1017, 0)->value, 0);
  ObjectDictionary dup;
  dup.add(0x1000, 0, OdType::u32, OdAccess::constant, 0);
  dup.add(0x1000, 0, OdType::u32, OdAccess::constant, 0);
  EXPECT_THROW(dup.freeze(), ObjectDictionaryError);
  ObjectDictionary bad;
  EXPECT_THROW(bad.add(0x1000, 0, OdType::u8, OdAccess::constant, 300), ObjectDictionaryError);
  EXPECT_THROW(od.at(0x9999, 0), ObjectDictionaryError);
}

}  // namespace
}  // namespace tendril::sim
