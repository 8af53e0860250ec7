#include <gtest/gtest.h>

#include <string>

#include "tendril/drivers/canopen/protocol.hpp"

namespace tendril::canopen {
namespace {

struct StatuswordCase {
  std::uint16_t statusword;
  Cia402State state;
};

// CiA 402 Table 30, with bits the pattern ignores set to both values.
TEST(Cia402, DecodesAllEightStates) {
  const StatuswordCase cases[] = {
      {0x0000, Cia402State::not_ready_to_switch_on},
      {0x0020, Cia402State::not_ready_to_switch_on},
      {0x0040, Cia402State::switch_on_disabled},
      {0x0060, Cia402State::switch_on_disabled},
      {0x0021, Cia402State::ready_to_switch_on},
      {0x0231, Cia402State::ready_to_switch_on},
      {0x0023, Cia402State::switched_on},
      {0x0233, Cia402State::switched_on},
      {0x0027, Cia402State::operation_enabled},
      {0x1637, Cia402State::operation_enabled},
      {0x0007, Cia402State::quick_stop_active},
      {0x0217, Cia402State::quick_stop_active},
      {0x000F, Cia402State::fault_reaction_active},
      {0x002F, Cia402State::fault_reaction_active},
      {0x0008, Cia402State::fault},
      {0x0228, Cia402State::fault},
  };
  for (const auto& c : cases) {
    EXPECT_EQ(decode_statusword(c.statusword), c.state)
        << "statusword 0x" << std::hex << c.statusword << " expected " << to_string(c.state) << " got "
        << to_string(decode_statusword(c.statusword));
  }
}

TEST(Cia402, EncodeRoundTripsForEveryState) {
  for (int s = 0; s <= static_cast<int>(Cia402State::fault); ++s) {
    const auto state = static_cast<Cia402State>(s);
    const std::uint16_t sw = encode_statusword(state);
    EXPECT_EQ(sw & ~0x6Fu, 0u) << to_string(state);  // only bits 0..3, 5, 6
    EXPECT_EQ(decode_statusword(sw), state) << to_string(state);
    EXPECT_EQ(decode_statusword(sw | statusword_bit::remote | statusword_bit::voltage_enabled), state);
  }
}

TEST(Cia402, UndefinedPatternIsNeverTakenForEnabled) {
  // 0x0001: ready bit without quick stop bit: not in the table.
  EXPECT_EQ(decode_statusword(0x0001), Cia402State::fault);
}

TEST(Cia402, StateNames) {
  EXPECT_STREQ(to_string(Cia402State::operation_enabled), "operation_enabled");
  EXPECT_STREQ(to_string(Cia402State::switch_on_disabled), "switch_on_disabled");
  EXPECT_STREQ(to_string(Cia402State::fault), "fault");
}

TEST(Sdo, AbortTexts) {
  EXPECT_EQ(std::string(sdo_abort_text(sdo_abort::no_object)),
            "object does not exist in the object dictionary");
  EXPECT_EQ(std::string(sdo_abort_text(sdo_abort::toggle_bit)), "toggle bit not alternated");
  EXPECT_EQ(std::string(sdo_abort_text(sdo_abort::timeout)), "SDO protocol timed out");
  EXPECT_NE(std::string(sdo_abort_text(sdo_abort::value_range)).find("value range"), std::string::npos);
  EXPECT_EQ(std::string(sdo_abort_text(0x1234'5678)), "unknown abort code");
}

TEST(Codec, LittleEndianHelpers) {
  std::uint8_t b[4]{};
  put_u32(b, 0x6040'0010);
  EXPECT_EQ(b[0], 0x10);
  EXPECT_EQ(b[3], 0x60);
  EXPECT_EQ(get_u32(b), 0x6040'0010u);
  put_u16(b, 0xBEEF);
  EXPECT_EQ(get_u16(b), 0xBEEF);
}

}  // namespace
}  // namespace tendril::canopen
