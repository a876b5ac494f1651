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

TEST(Cli, FoldersAndListsOfInputs) {
    test::TempDir dir;
    // Three small text scans: two in a folder tree (with a file no reader takes),
    // one named by a list with a relative path, a comment and a blank line.
    std::filesystem::create_directories(dir.file("scans/deeper"));
    auto xyz = [&](const std::string& path, int n, double z) {
        std::string text;
        for (int i = 0; i < n; ++i) text += std::to_string(i * 0.01) + " " + std::to_string((i % 7) * 0.01) + " " + std::to_string(z) + "\n";
        test::writeFile(path, text);
    };
    xyz(dir.file("scans/a.xyz"), 100, 0);
    xyz(dir.file("scans/deeper/b.xyz"), 200, 1);
    test::writeFile(dir.file("scans/notes.md"), "not a scan");
    xyz(dir.file("c.xyz"), 300, 2);
    test::writeFile(dir.file("list.txt"), "# inputs\n\nc.xyz\n");
    auto r = test::run({test::binary("surfcast-build"), "-q", dir.file("scans"), "@" + dir.file("list.txt"), "-o", dir.file("s")});
    ASSERT_EQ(r.exitCode, 0) << r.output;
    EXPECT_NE(r.output.find("points in: 600 "), std::string::npos) << r.output;

    auto missing = test::run({test::binary("surfcast-build"), "@" + dir.file("nope.txt"), "-o", dir.file("t")});
    EXPECT_EQ(missing.exitCode, 1);
    EXPECT_NE(missing.output.find("nope.txt: cannot open the input list"), std::string::npos) << missing.output;
    std::filesystem::create_directories(dir.file("empty"));
    auto empty = test::run({test::binary("surfcast-build"), dir.file("empty"), "-o", dir.file("t")});
    EXPECT_EQ(empty.exitCode, 1);
    EXPECT_NE(empty.output.find("holds no file of a readable format"), std::string::npos) << empty.output;
    EXPECT_FALSE(std::filesystem::exists(dir.file("t")));
}
