// `specula bench trace` packet rows (owner: accel): the coherent primary and shadow rays traced
// as 16-ray packets beside Embree's rtcIntersect16 / rtcOccluded16, in the table and in --json.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "cli_test_util.h"
#include "specula/accel.h"
#include "test_util.h"

namespace fs = std::filesystem;

namespace {

using specula::test::RunResult;
using specula::test::run_cli;

class BenchTracePackets : public ::testing::Test {
 protected:
  void SetUp() override {
    if (std::string(SPECULA_CLI_PATH).empty()) GTEST_SKIP() << "specula CLI not built";
    dir_ = specula::test::temp_dir(::testing::UnitTest::GetInstance()->current_test_info()->name());
  }
  void TearDown() override {
    if (!dir_.empty()) fs::remove_all(dir_);
  }
  fs::path dir_;
};

TEST_F(BenchTracePackets, JsonHasPrimaryAndShadowPacketRows) {
  const RunResult r = run_cli("bench trace --scene cornell --width 36 --height 20 --repeat 1 --json", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  nlohmann::json j;
  ASSERT_NO_THROW(j = nlohmann::json::parse(r.out)) << r.out;
  ASSERT_TRUE(j.contains("packets")) << r.out;
  std::vector<std::string> kinds;
  for (const auto& k : j["packets"]) {
    kinds.push_back(k["kind"].get<std::string>());
    EXPECT_EQ(k["order"], "4x4 pixel blocks");
    EXPECT_EQ(k["packet_rays"].get<int>(), specula::bvh_packet_rays(specula::BvhKernel::Auto)) << k.dump();
    EXPECT_GT(k["count"].get<int>(), 0) << k.dump();
    EXPECT_GT(k["specula_1t"].get<double>(), 0.0) << k.dump();
    EXPECT_GT(k["specula_nt"].get<double>(), 0.0) << k.dump();
    // The cornell box seen from its camera: almost every block is coherent.
    EXPECT_GT(k["in_packets"].get<double>(), 0.5) << k.dump();
    EXPECT_LE(k["in_packets"].get<double>(), 1.0) << k.dump();
    if (j["embree"].get<bool>()) {
      EXPECT_EQ(k["embree"], k["kind"] == "shadow" ? "rtcOccluded16" : "rtcIntersect16");
      EXPECT_GT(k["embree_1t"].get<double>(), 0.0) << k.dump();
      EXPECT_GT(k["ratio_1t"].get<double>(), 0.0) << k.dump();
    }
  }
  EXPECT_EQ(kinds, (std::vector<std::string>{"primary", "shadow"}));
  // 36 x 20 pixels in 4x4 blocks: every primary ray once.
  EXPECT_EQ(j["packets"][0]["count"].get<int>(), 36 * 20);
}

TEST_F(BenchTracePackets, TableHasThePacketSection) {
  const RunResult r = run_cli("bench trace --scene cornell --width 24 --height 16 --repeat 1 --no-embree", dir_);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("packets: rays in 4x4 pixel blocks, traced " + std::to_string(specula::bvh_packet_rays(specula::BvhKernel::Auto)) +
                       " at a time by ours"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("in pkts"), std::string::npos) << r.out;
}

}  // namespace
