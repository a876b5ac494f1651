#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "test_support.h"

using namespace surfcast;

TEST(Cli, HelpAndUsageErrors) {
    auto help = test::run({test::binary("surfcast-build"), "--help"});
    EXPECT_EQ(help.exitCode, 0);
    EXPECT_NE(help.output.find("usage: surfcast-build"), std::string::npos);
    auto unknown = test::run({test::binary("surfcast-build"), "--bogus"});
    EXPECT_EQ(unknown.exitCode, 2);
    EXPECT_NE(unknown.output.find("unknown option --bogus"), std::string::npos);
    auto noOut = test::run({test::binary("surfcast-build"), "--default-scene"});
    EXPECT_EQ(noOut.exitCode, 2);
    auto badMem = test::run({test::binary("surfcast-build"), "--default-scene", "-o", "/tmp/x", "--memory", "lots"});
    EXPECT_EQ(badMem.exitCode, 2);
}

TEST(Cli, InfoVerifiesChecksums) {
    test::TempDir dir;
    auto b = test::run({test::binary("surfcast-build"), "--default-scene", "--scene-points", "50000", "-o", dir.file("s")});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    EXPECT_NE(b.output.find("level 0:"), std::string::npos) << b.output;
    EXPECT_NE(b.output.find("peak RSS"), std::string::npos) << b.output;
    auto info = test::run({test::binary("surfcast-build"), "--info", dir.file("s")});
    ASSERT_EQ(info.exitCode, 0) << info.output;
    EXPECT_NE(info.output.find("checksums verified"), std::string::npos) << info.output;

    // Flip one byte in the middle of blocks.bin: --info names the node and the CRC.
    std::string blocks = dir.file("s/blocks.bin");
    auto size = std::filesystem::file_size(blocks);
    std::fstream f(blocks, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(std::streamoff(size / 2));
    char c = 0;
    f.get(c);
    f.seekp(std::streamoff(size / 2));
    f.put(char(c ^ 0x10));
    f.close();
    auto bad = test::run({test::binary("surfcast-build"), "--info", dir.file("s")});
    EXPECT_EQ(bad.exitCode, 1);
    EXPECT_NE(bad.output.find("CRC mismatch"), std::string::npos) << bad.output;
}

TEST(Cli, RefusesToReplaceSomethingElse) {
    test::TempDir dir;
    std::filesystem::create_directories(dir.file("precious"));
    test::writeFile(dir.file("precious/data.txt"), "keep me");
    auto r = test::run({test::binary("surfcast-build"), "--default-scene", "--scene-points", "1000", "-o", dir.file("precious")});
    EXPECT_EQ(r.exitCode, 1);
    EXPECT_NE(r.output.find("not a tile set"), std::string::npos) << r.output;
    EXPECT_EQ(test::readFile(dir.file("precious/data.txt")), "keep me");
}
