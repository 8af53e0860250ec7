#include <gtest/gtest.h>

#include "tendril/drivers/can/virtual_bus.hpp"
#include "tendril/drivers/canopen/sdo_client.hpp"

namespace tendril::canopen {
namespace {

using namespace std::chrono_literals;
using can::Frame;

constexpr std::uint8_t kNode = 5;

// The client on one endpoint, a scripted server on the other. Time is passed in by hand.
class SdoClientTest : public ::testing::Test {
 protected:
  can::VirtualBus bus_{"sdo"};
  std::unique_ptr<can::VirtualBusEndpoint> client_ep_ = bus_.attach("client");
  std::unique_ptr<can::VirtualBusEndpoint> server_ep_ = bus_.attach("server");
  SdoClient sdo_{*client_ep_, kNode, 100ms, 1};
  can::Clock::time_point now_ = can::Clock::now();

  Frame request() {
    auto f = server_ep_->receive(0ns);
    EXPECT_TRUE(f) << "the client sent nothing";
    if (!f) return Frame{};
    EXPECT_EQ(f->id, cob::sdo_rx + kNode);
    EXPECT_EQ(f->len, 8);
    return *f;
  }
  void answer(std::array<std::uint8_t, 8> bytes) {
    Frame f;
    f.id = cob::sdo_tx + kNode;
    f.len = 8;
    f.data = bytes;
    server_ep_->send(f);
    while (auto g = client_ep_->receive(0ns)) EXPECT_TRUE(sdo_.handle(*g, now_));
  }
};

TEST_F(SdoClientTest, ExpeditedDownloadEncodesSizeIndexAndData) {
  const std::pair<std::vector<std::uint8_t>, std::uint8_t> cases[] = {
      {{0x11}, 0x2F}, {{0x11, 0x22}, 0x2B}, {{0x11, 0x22, 0x33}, 0x27}, {{0x11, 0x22, 0x33, 0x44}, 0x23}};
  for (const auto& [data, command] : cases) {
    sdo_.start_download(0x1017, 0x00, data, now_);
    EXPECT_TRUE(sdo_.busy());
    const Frame r = request();
    EXPECT_EQ(r.data[0], command);
    EXPECT_EQ(r.data[1], 0x17);
    EXPECT_EQ(r.data[2], 0x10);
    EXPECT_EQ(r.data[3], 0x00);
    for (std::size_t i = 0; i < data.size(); ++i) EXPECT_EQ(r.data[4 + i], data[i]);
    answer({0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0});
    EXPECT_EQ(sdo_.status(), SdoClient::Status::done);
  }
}

TEST_F(SdoClientTest, SegmentedDownloadAlternatesToggleAndMarksLastSegment) {
  const std::vector<std::uint8_t> data{1, 2, 3, 4, 5, 6, 7, 8, 9, 10};
  sdo_.start_download(0x2000, 0x01, data, now_);
  Frame r = request();
  EXPECT_EQ(r.data[0], 0x21);  // segmented, size indicated
  EXPECT_EQ(get_u32(&r.data[4]), 10u);
  answer({0x60, 0x00, 0x20, 0x01, 0, 0, 0, 0});
  r = request();
  EXPECT_EQ(r.data[0], 0x00);  // toggle 0, 7 bytes, more to come
  EXPECT_EQ(r.data[1], 1);
  EXPECT_EQ(r.data[7], 7);
  answer({0x20, 0, 0, 0, 0, 0, 0, 0});
  EXPECT_TRUE(sdo_.busy());
  r = request();
  EXPECT_EQ(r.data[0], 0x10 | (4 << 1) | 0x01);  // toggle 1, 3 bytes used, last
  EXPECT_EQ(r.data[1], 8);
  EXPECT_EQ(r.data[3], 10);
  answer({0x30, 0, 0, 0, 0, 0, 0, 0});
  EXPECT_EQ(sdo_.status(), SdoClient::Status::done);
}

TEST_F(SdoClientTest, DownloadSegmentWithWrongToggleAbortsTheTransfer) {
  sdo_.start_download(0x2000, 0x01, std::vector<std::uint8_t>(9, 0xAB), now_);
  request();
  answer({0x60, 0x00, 0x20, 0x01, 0, 0, 0, 0});
  request();
  answer({0x30, 0, 0, 0, 0, 0, 0, 0});  // toggle 1 where 0 was sent
  EXPECT_EQ(sdo_.status(), SdoClient::Status::failed);
  EXPECT_EQ(sdo_.abort_code(), sdo_abort::toggle_bit);
  const Frame abort = request();
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(get_u16(&abort.data[1]), 0x2000);
  EXPECT_EQ(abort.data[3], 0x01);
  EXPECT_EQ(get_u32(&abort.data[4]), sdo_abort::toggle_bit);
}

TEST_F(SdoClientTest, ExpeditedUpload) {
  sdo_.start_upload(0x6041, 0x00, now_);
  const Frame r = request();
  EXPECT_EQ(r.data[0], 0x40);
  EXPECT_EQ(get_u16(&r.data[1]), 0x6041);
  answer({0x4B, 0x41, 0x60, 0x00, 0x37, 0x02, 0, 0});  // 2 bytes
  ASSERT_EQ(sdo_.status(), SdoClient::Status::done);
  ASSERT_EQ(sdo_.upload_data().size(), 2u);
  EXPECT_EQ(get_u16(sdo_.upload_data().data()), 0x0237);
}

TEST_F(SdoClientTest, SegmentedUploadCollectsAllSegments) {
  sdo_.start_upload(0x1008, 0x00, now_);
  request();
  answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0});  // segmented, 10 bytes
  Frame r = request();
  EXPECT_EQ(r.data[0], 0x60);  // upload segment, toggle 0
  answer({0x00, 'c', 'a', 't', 'h', 'e', 't', 'e'});
  r = request();
  EXPECT_EQ(r.data[0], 0x70);  // toggle 1
  answer({0x10 | (4 << 1) | 1, 'r', '-', '1', 0, 0, 0, 0});
  ASSERT_EQ(sdo_.status(), SdoClient::Status::done) << sdo_.error();
  EXPECT_EQ(std::string(sdo_.upload_data().begin(), sdo_.upload_data().end()), "catheter-1");
}

TEST_F(SdoClientTest, UploadSegmentWithWrongToggleFails) {
  sdo_.start_upload(0x1008, 0x00, now_);
  request();
  answer({0x41, 0x08, 0x10, 0x00, 10, 0, 0, 0});
  request();
  answer({0x10, 'x', 'x', 'x', 'x', 'x', 'x', 'x'});
  EXPECT_EQ(sdo_.status(), SdoClient::Status::failed);
  EXPECT_EQ(sdo_.abort_code(), sdo_abort::toggle_bit);
}

TEST_F(SdoClientTest, ServerAbortBecomesAMessageNamingNodeObjectAndReason) {
  sdo_.start_download(0x6060, 0x00, {0x08}, now_);
  request();
  answer({0x80, 0x60, 0x60, 0x00, 0x30, 0x00, 0x09, 0x06});  // 0x06090030 value range
  EXPECT_EQ(sdo_.status(), SdoClient::Status::failed);
  EXPECT_EQ(sdo_.abort_code(), sdo_abort::value_range);
  const std::string& msg = sdo_.error();
  EXPECT_NE(msg.find("node 5"), std::string::npos) << msg;
  EXPECT_NE(msg.find("0x6060:0x00"), std::string::npos) << msg;
  EXPECT_NE(msg.find("0x06090030"), std::string::npos) << msg;
  EXPECT_NE(msg.find("value range"), std::string::npos) << msg;
  EXPECT_FALSE(server_ep_->receive(0ns));  // no abort sent back for the server's own abort
}

TEST_F(SdoClientTest, AnswerForAnotherObjectIsRejected) {
  sdo_.start_download(0x6060, 0x00, {0x08}, now_);
  request();
  answer({0x60, 0x61, 0x60, 0x00, 0, 0, 0, 0});
  EXPECT_EQ(sdo_.status(), SdoClient::Status::failed);
}

TEST_F(SdoClientTest, TimeoutRetriesTheWholeTransferThenSucceeds) {
  sdo_.start_download(0x1017, 0x00, {20, 0}, now_);
  const Frame first = request();  // ignored by the server
  sdo_.poll(now_ + 99ms);
  EXPECT_FALSE(server_ep_->receive(0ns));  // not yet
  sdo_.poll(now_ + 100ms);
  const Frame second = request();
  EXPECT_EQ(second.data, first.data);
  EXPECT_EQ(sdo_.retries_used(), 1u);
  answer({0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0});
  EXPECT_EQ(sdo_.status(), SdoClient::Status::done);
}

TEST_F(SdoClientTest, TimeoutAfterAllRetriesFailsAndSendsAnAbort) {
  sdo_.start_download(0x1017, 0x00, {20, 0}, now_);
  request();
  sdo_.poll(now_ + 100ms);
  request();  // the retry
  sdo_.poll(now_ + 150ms);
  EXPECT_TRUE(sdo_.busy());  // the retry's own timeout runs from its send time
  sdo_.poll(now_ + 200ms);
  EXPECT_EQ(sdo_.status(), SdoClient::Status::failed);
  EXPECT_EQ(sdo_.abort_code(), sdo_abort::timeout);
  EXPECT_NE(sdo_.error().find("no answer within 100 ms (2 attempts)"), std::string::npos) << sdo_.error();
  const Frame abort = request();
  EXPECT_EQ(abort.data[0], 0x80);
  EXPECT_EQ(get_u32(&abort.data[4]), sdo_abort::timeout);
}

TEST_F(SdoClientTest, IgnoresFramesOfOtherNodes) {
  sdo_.start_upload(0x6041, 0x00, now_);
  Frame other;
  other.id = cob::sdo_tx + kNode + 1;
  other.len = 8;
  EXPECT_FALSE(sdo_.handle(other, now_));
  EXPECT_TRUE(sdo_.busy());
}

}  // namespace
}  // namespace tendril::canopen
