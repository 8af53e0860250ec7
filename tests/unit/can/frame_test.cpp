#include <gtest/gtest.h>

#include "tendril/drivers/can/frame.hpp"

namespace tendril::can {
namespace {

TEST(Frame, MakeCopiesBytesAndClampsLength) {
  const Frame f = Frame::make(0x181, {1, 2, 3});
  EXPECT_EQ(f.id, 0x181u);
  EXPECT_EQ(f.len, 3);
  EXPECT_EQ(f.data[2], 3);
  const Frame g = Frame::make(0x1, {1, 2, 3, 4, 5, 6, 7, 8, 9, 10});
  EXPECT_EQ(g.len, 8);
  EXPECT_EQ(g.data[7], 8);
}

TEST(Frame, FormatStandardExtendedRtrAndError) {
  EXPECT_EQ(format_frame(Frame::make(0x123, {0xDE, 0xAD, 0xBE, 0xEF})), "123#DEADBEEF");
  EXPECT_EQ(format_frame(Frame::make(0x80, {})), "080#");
  Frame ext = Frame::make(0x1ABCDEF, {0x01});
  ext.extended = true;
  EXPECT_EQ(format_frame(ext), "01ABCDEF#01");
  Frame rtr = Frame::make(0x701, {});
  rtr.rtr = true;
  EXPECT_EQ(format_frame(rtr), "701#R");
  Frame err;
  err.error = true;
  err.id = error_class::bus_off;
  err.len = 0;
  EXPECT_EQ(format_frame(err), "00000040# (error frame)");
}

TEST(Frame, EnumNames) {
  EXPECT_STREQ(to_string(BusState::bus_off), "bus_off");
  EXPECT_STREQ(to_string(BusState::error_passive), "error_passive");
  EXPECT_STREQ(to_string(SendResult::would_block), "would_block");
  EXPECT_STREQ(to_string(SendResult::too_long), "too_long");
}

}  // namespace
}  // namespace tendril::can
