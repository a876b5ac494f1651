// Remote hosts (net/http_tile_source): nginx serving a set as static
// files to the headless viewer and the window, over plain HTTP and over TLS with HTTP/2 and HTTP/1.1 (certificates
// from the test's own CA); bearer tokens, headers, signed query strings,
// redirects and their loops; a certificate that does not verify; lazily
// fetched hierarchy pages; a host without Range; surfcast-serve over HTTPS.
#include <gtest/gtest.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "stream_support.h"
#include "test_support.h"

namespace surfcast {
namespace {

using test::binary;
using test::expectStreamsLikeLocal;
using test::run;
using test::TempDir;
using test::freePort;
using test::startNginx;

TEST(Stream, FromNginxConvergesToTheLocalImage) {
    // nginx serving the same folder as static files: Range requests only
    // (its answers offer no batches, so it is never sent a POST).
    TempDir dir;
    std::filesystem::create_directories(dir.file("www/sets"));
    auto b = test::buildScene(dir.file("www/sets/scene"), 100000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    // /served/ redirects to surfcast-serve, whose answers offer batches at
    // its own URL; the client's POSTs would go to nginx's (not redirected),
    // so after a redirect it takes ranges.
    test::Child server;
    const std::string origin = test::startServer(&server, dir.file("www/sets"));
    ASSERT_FALSE(origin.empty()) << server.log;
    auto nginx = startNginx(dir.file("nginx"), 1, [&](const std::vector<int>& ports) {
        return " server { listen 127.0.0.1:" + std::to_string(ports[0]) + "; root " + dir.file("www") + ";\n"
               "  location /served/ { rewrite ^/served/(.*)$ " + origin + "/sets/$1 redirect; } }\n";
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string url = "http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/sets/scene";
    const char* camera = "--camera=3,-6,2,0,0,0.5,0,0,1,50";
    expectStreamsLikeLocal(url, dir.file("www/sets/scene"), camera, dir);
    expectStreamsLikeLocal("http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/served/scene", dir.file("www/sets/scene"),
                           camera, dir);
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0);

    // Without --lod every leaf is fetched before the first frame, which is
    // then the local folder's headless frame: in the window, under Xvfb, and
    // headless under TSan, which leaves GLFW's window out as it does
    // stream_test's (bench/RELIABILITY.md, "What each CI stage covers"). With
    // --lod the window streams and closes after its frames.
    auto headless = run({binary("surfcast-view"), "--headless", dir.file("www/sets/scene"), camera, "--size", "200x150",
                         "--out", dir.file("headless.png")});
    ASSERT_EQ(headless.exitCode, 0) << headless.output;
#if defined(SURFCAST_TSAN)
    auto whole = run({binary("surfcast-view"), "--headless", url, camera, "--size", "200x150", "--out", dir.file("whole.png")});
#else
    auto whole = run({"/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", binary("surfcast-view"), url, camera,
                      "--size", "200x150", "--frames", "3", "--screenshot", dir.file("whole.png")});
#endif
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    EXPECT_TRUE(test::readFile(dir.file("whole.png")) == test::readFile(dir.file("headless.png")))
        << "the URL's frame without --lod differs from the folder's headless frame";
#if !defined(SURFCAST_TSAN)
    auto streaming = run({"/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", binary("surfcast-view"), url, camera,
                          "--lod", "1", "--size", "200x150", "--frames", "30", "--screenshot", dir.file("streaming.png")});
    EXPECT_EQ(streaming.exitCode, 0) << streaming.output;
    EXPECT_TRUE(std::filesystem::exists(dir.file("streaming.png"))) << streaming.output;
#endif
}

// The client fetches hierarchy.bin's header, page table and page 0, then the
// pages traversal reaches (docs/FORMAT.md). A set paged every 2 levels: a
// close-up reaches few of its 146 pages, and an overview more, each fewer
// than the whole file; both converge to the image of the same set in one
// page, which the client takes whole at open (a full download).
TEST(Stream, PagedHierarchyFetchesOnlyThePagesAViewReaches) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("www/sets"));
    for (const char* depth : {"2", "21"}) {
        auto b = test::buildScene(dir.file(std::string("www/sets/d") + depth), 100000,
                                  {"--capacity", "500", "--page-depth", depth});
        ASSERT_EQ(b.exitCode, 0) << b.output;
    }
    const auto paged = std::filesystem::file_size(dir.file("www/sets/d2/hierarchy.bin"));
    const auto whole = std::filesystem::file_size(dir.file("www/sets/d21/hierarchy.bin"));
    auto nginx = startNginx(dir.file("nginx"), 1, [&](const std::vector<int>& ports) {
        return " server { listen 127.0.0.1:" + std::to_string(ports[0]) + "; root " + dir.file("www") + "; }\n";
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string url = "http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/sets/";
    const char* closeUp = "--camera=0.6,-1.2,0.9,0.3,0,0.5,0,0,1,25";
    const char* overview = "--camera=3,-6,2,0,0,0.5,0,0,1,50";
    auto near = expectStreamsLikeLocal(url + "d2", dir.file("www/sets/d21"), closeUp, dir);
    auto far = expectStreamsLikeLocal(url + "d2", dir.file("www/sets/d21"), overview, dir);
    auto one = expectStreamsLikeLocal(url + "d21", dir.file("www/sets/d21"), overview, dir);
    ASSERT_TRUE(near.is_object() && far.is_object() && one.is_object());
    EXPECT_EQ(one["hierarchy_pages"].get<int>(), 1);
    EXPECT_EQ(one["hierarchy_bytes"].get<uint64_t>(), whole);
    EXPECT_GT(near["hierarchy_pages"].get<int>(), 1) << "the close-up needs pages below page 0";
    EXPECT_LT(near["hierarchy_bytes"].get<uint64_t>(), far["hierarchy_bytes"].get<uint64_t>());
    EXPECT_LT(far["hierarchy_bytes"].get<uint64_t>(), paged);
}

// A static host that ignores Range (Python's http.server answers 200 with
// the whole file) gets one clear error, not a confusing transfer failure
// (libcurl's "Failure writing output" when the unwanted body was dropped).
TEST(Stream, AHostWithoutRangeSupportIsNamed) {
    TempDir dir;
    auto b = test::buildScene(dir.file("www/scene"), 20000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    const int port = freePort();
    test::Child server = test::spawn(
        {"/usr/bin/python3", "-c",
         "import functools, http.server, sys\n"
         "s = http.server.ThreadingHTTPServer(('127.0.0.1', " + std::to_string(port) + "), functools.partial("
         "http.server.SimpleHTTPRequestHandler, directory=sys.argv[1]))\n"
         "print('listening', file=sys.stderr, flush=True)\n"
         "s.serve_forever()\n",
         dir.file("www")});
    ASSERT_TRUE(server.waitFor("listening")) << server.log;
    const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/scene";
    auto info = run({binary("surfcast-build"), "--info", url});
    auto view = run({binary("surfcast-view"), "--headless", url, "--lod", "1", "--size", "64x48", "--out", dir.file("x.png")});
    ::kill(server.pid, SIGTERM);
    test::exitCode(server.pid);
    for (const auto* r : {&info, &view}) {
        EXPECT_NE(r->exitCode, 0);
        EXPECT_NE(r->output.find(".bin: the host ignores Range requests"), std::string::npos) << r->output;
    }
}

// A CA and a server certificate for 127.0.0.1 it signs, made with openssl in
// `dir`: ca.pem, server.pem, server.key; and an unrelated CA, other.pem.
void makeCertificates(const TempDir& dir) {
    auto ssl = [&](std::vector<std::string> args) {
        args.insert(args.begin(), "/usr/bin/openssl");
        auto r = run(args);
        ASSERT_EQ(r.exitCode, 0) << r.output;
    };
    test::writeFile(dir.file("san.cnf"), "subjectAltName=IP:127.0.0.1\n");
    for (const char* ca : {"ca", "other"})
        ssl({"req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", dir.file(std::string(ca) + ".key"), "-out",
             dir.file(std::string(ca) + ".pem"), "-days", "2", "-subj", std::string("/CN=surfcast test ") + ca});
    ssl({"req", "-newkey", "rsa:2048", "-nodes", "-keyout", dir.file("server.key"), "-out", dir.file("server.csr"), "-subj",
         "/CN=127.0.0.1"});
    ssl({"x509", "-req", "-in", dir.file("server.csr"), "-CA", dir.file("ca.pem"), "-CAkey", dir.file("ca.key"),
         "-CAcreateserial", "-out", dir.file("server.pem"), "-days", "2", "-extfile", dir.file("san.cnf")});
}

TEST(Stream, OverHttpsFromNginxWithHttp2AndHttp11) {
    // nginx with TLS (a certificate from the test's own CA) on two ports,
    // HTTP/2 on the first and HTTP/1.1 only on the second. Locations: the
    // set; one that wants a bearer token; one that wants a signature in the
    // query string (as a shared access signature); one that redirects to the
    // set; one that redirects to itself.
    TempDir dir;
    std::filesystem::create_directories(dir.file("www/sets"));
    auto b = test::buildScene(dir.file("www/sets/scene"), 100000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    makeCertificates(dir);
    for (const char* place : {"private", "signed"}) {
        std::filesystem::create_directories(dir.file("www/") + place);
        std::filesystem::create_directory_symlink(dir.file("www/sets/scene"), dir.file("www/") + place + "/scene");
    }
    test::writeFile(dir.file("token"), "s3cret-Token\n");
    auto nginx = startNginx(dir.file("nginx"), 2, [&](const std::vector<int>& ports) {
        std::string s;
        for (size_t i = 0; i < 2; ++i)
            s += std::string(i == 0 ? " log_format conn '$connection \"$request\" $status';\n" : "") +
                 " server {\n  listen 127.0.0.1:" + std::to_string(ports[i]) + (i == 0 ? " ssl http2;\n" : " ssl;\n") +
                 "  ssl_certificate " + dir.file("server.pem") + "; ssl_certificate_key " + dir.file("server.key") + ";\n"
                 "  access_log " + dir.file("access.log") + " conn;\n  root " + dir.file("www") + ";\n"
                 "  location /private/ { if ($http_authorization != \"Bearer s3cret-Token\") { return 401; } }\n"
                 "  location /signed/ { if ($arg_sig != \"abc\") { return 403; } }\n"
                 "  location /moved/ { rewrite ^/moved/(.*)$ /sets/$1 redirect; }\n"
                 "  location /loop/ { rewrite ^/loop/(.*)$ /loop/$1 redirect; }\n }\n";
        return s;
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string local = dir.file("www/sets/scene"), camera = "--camera=3,-6,2,0,0,0.5,0,0,1,50";
    const std::string h2 = "https://127.0.0.1:" + std::to_string(nginx->ports[0]),
                      h1 = "https://127.0.0.1:" + std::to_string(nginx->ports[1]);
    const std::vector<std::string> ca = {"--ca-file", dir.file("ca.pem")};

    // The streamed image equals the local one byte for byte, over either
    // protocol. Over HTTP/2 every request shares one connection (nginx logs
    // each request's connection number first); over HTTP/1.1 up to 6.
    size_t logged = 0;  // bytes of the log already looked at
    auto connections = [&](const std::string& protocol) {
        std::set<std::string> ids;
        const std::string all = test::readFile(dir.file("access.log"));
        std::istringstream log(all.substr(std::min(logged, all.size())));
        logged = all.size();
        size_t ranges = 0;
        for (std::string line; std::getline(log, line);) {
            EXPECT_NE(line.find(protocol + "\" "), std::string::npos) << line;
            // nginx offers no batches (no Surfcast-Batch): never probed with a POST.
            EXPECT_EQ(line.find("\"POST "), std::string::npos) << line;
            ranges += line.find(protocol + "\" 206") != std::string::npos;
            ids.insert(line.substr(0, line.find(' ')));
        }
        EXPECT_GT(ranges, 10u) << "few " << protocol << " range requests in nginx's log";
        return ids.size();
    };
    expectStreamsLikeLocal(h2 + "/sets/scene", local, camera.c_str(), dir, ca);
    EXPECT_EQ(connections("HTTP/2.0"), 1u);
    expectStreamsLikeLocal(h1 + "/sets/scene", local, camera.c_str(), dir, ca);
    const size_t http1 = connections("HTTP/1.1");
    EXPECT_GE(http1, 2u);
    EXPECT_LE(http1, 6u);

    // Without --lod: every leaf, fetched whole, the same image as the folder.
    auto remote = run({binary("surfcast-view"), "--headless", h2 + "/sets/scene", camera, "--size", "200x150", "--ca-file",
                       dir.file("ca.pem"), "--out", dir.file("remote-all.png")});
    ASSERT_EQ(remote.exitCode, 0) << remote.output;
    auto folder = run({binary("surfcast-view"), "--headless", local, camera, "--size", "200x150", "--out", dir.file("local-all.png")});
    ASSERT_EQ(folder.exitCode, 0) << folder.output;
    EXPECT_TRUE(test::readFile(dir.file("remote-all.png")) == test::readFile(dir.file("local-all.png")));

    // A certificate that does not verify: one clear error at once, no retries.
    for (const std::vector<std::string>& trust : {std::vector<std::string>{"--ca-file", dir.file("other.pem")},
                                                   std::vector<std::string>{}}) {
        std::vector<std::string> args = {binary("surfcast-view"), "--headless", h2 + "/sets/scene", "--lod", "1", "--size",
                                         "64x48", "--out", dir.file("x.png")};
        args.insert(args.end(), trust.begin(), trust.end());
        const auto start = std::chrono::steady_clock::now();
        auto r = run(args);
        EXPECT_NE(r.exitCode, 0);
        EXPECT_NE(r.output.find(h2 + "/sets/scene/tileset.json: TLS with the host failed"), std::string::npos) << r.output;
        EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 10.0);
    }

    // A bearer token from a file opens the private location; without it, 401
    // names the URL and the remedy. The token is never printed.
    auto refused = run({binary("surfcast-view"), "--headless", h2 + "/private/scene", "--lod", "1", "--size", "64x48",
                        "--ca-file", dir.file("ca.pem"), "--out", dir.file("x.png")});
    EXPECT_NE(refused.exitCode, 0);
    EXPECT_NE(refused.output.find(h2 + "/private/scene/tileset.json: HTTP 401"), std::string::npos) << refused.output;
    EXPECT_NE(refused.output.find("--token-file"), std::string::npos) << refused.output;
    auto last = expectStreamsLikeLocal(h2 + "/private/scene", local, camera.c_str(), dir,
                                       {"--ca-file", dir.file("ca.pem"), "--token-file", dir.file("token")});
    EXPECT_EQ(last.dump().find("s3cret"), std::string::npos);
    auto header = run({binary("surfcast-view"), "--headless", h1 + "/private/scene", "--size", "64x48", "--ca-file",
                       dir.file("ca.pem"), "--header", "Authorization: Bearer s3cret-Token", "--out", dir.file("x.png")});
    EXPECT_EQ(header.exitCode, 0) << header.output;
    EXPECT_EQ(header.output.find("s3cret"), std::string::npos) << header.output;

    // The query string travels with every request (a prefix-scoped signature).
    expectStreamsLikeLocal(h1 + "/signed/scene?sig=abc", local, camera.c_str(), dir, ca);

    // surfcast-build --info reaches the same hosts the same way: its summary
    // of the signed URL is the folder's but for the name in the first line,
    // which leaves the signature out.
    auto infoLocal = run({binary("surfcast-build"), "--info", local});
    ASSERT_EQ(infoLocal.exitCode, 0) << infoLocal.output;
    auto infoRemote = run({binary("surfcast-build"), "--info", h1 + "/signed/scene?sig=abc", "--ca-file", dir.file("ca.pem")});
    ASSERT_EQ(infoRemote.exitCode, 0) << infoRemote.output;
    EXPECT_EQ(infoRemote.output.substr(0, infoRemote.output.find(": ")), h1 + "/signed/scene");
    EXPECT_EQ(infoRemote.output.substr(infoRemote.output.find(": ")), infoLocal.output.substr(infoLocal.output.find(": ")));
    auto infoRefused = run({binary("surfcast-build"), "--info", h2 + "/private/scene", "--ca-file", dir.file("ca.pem")});
    EXPECT_EQ(infoRefused.exitCode, 1);
    EXPECT_NE(infoRefused.output.find(h2 + "/private/scene/tileset.json: HTTP 401"), std::string::npos) << infoRefused.output;
    auto infoToken = run({binary("surfcast-build"), "--info", h2 + "/private/scene", "--ca-file", dir.file("ca.pem"),
                          "--token-file", dir.file("token")});
    EXPECT_EQ(infoToken.exitCode, 0) << infoToken.output;

    // Redirects are followed; a loop is an error.
    expectStreamsLikeLocal(h2 + "/moved/scene", local, camera.c_str(), dir, ca);
    auto loop = run({binary("surfcast-view"), "--headless", h2 + "/loop/scene", "--lod", "1", "--size", "64x48",
                     "--ca-file", dir.file("ca.pem"), "--out", dir.file("x.png")});
    EXPECT_NE(loop.exitCode, 0);
    EXPECT_NE(loop.output.find("redirects (a loop?)"), std::string::npos) << loop.output;
}

// Redirects (net/http_tile_source.h): an https set is never sent on to plain
// http nor to a scheme but http(s), and the user's credentials (--header,
// --token-file) go to the set's own origin only, unless
// --redirect-credentials. nginx on three loopback origins: A (https) wants
// the credentials and redirects; B (http) and C (https, another port) serve
// the set to anyone and log the headers they were sent.
TEST(Stream, RedirectsKeepCredentialsAtHomeAndNeverDowngrade) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("www/sets"));
    auto b = test::buildScene(dir.file("www/sets/scene"), 20000, {"--capacity", "2000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    makeCertificates(dir);
    test::writeFile(dir.file("token"), "s3cret-Token\n");
    auto nginx = startNginx(dir.file("nginx"), 3, [&](const std::vector<int>& ports) {
        const std::string tls = " ssl;\n  ssl_certificate " + dir.file("server.pem") + "; ssl_certificate_key " +
                                dir.file("server.key") + ";\n";
        const std::string a = std::to_string(ports[0]), http = std::to_string(ports[1]), other = std::to_string(ports[2]);
        auto check = "if ($http_authorization != \"Bearer s3cret-Token\") { return 401; } "
                     "if ($http_x_api_key != \"k3y-secret\") { return 401; } ";
        return " log_format sent '\"$request\" auth=\"$http_authorization\" key=\"$http_x_api_key\"';\n"
               " server {\n  listen 127.0.0.1:" + a + tls + "  root " + dir.file("www") + ";\n"
               "  access_log " + dir.file("a.log") + " sent;\n"
               "  location /sets/ { " + check + "}\n"
               "  location /away/ { " + check + "rewrite ^/away/(.*)$ https://127.0.0.1:" + other + "/sets/$1 redirect; }\n"
               "  location /down/ { " + check + "rewrite ^/down/(.*)$ http://127.0.0.1:" + http + "/sets/$1 redirect; }\n"
               "  location /locked/ { " + check + "rewrite ^/locked/(.*)$ https://127.0.0.1:" + other + "/locked/$1 redirect; }\n"
               "  location /ftp/ { return 302 ftp://127.0.0.1:" + http + "/sets/scene/tileset.json; }\n"
               "  location /here/ { " + check + "absolute_redirect off; rewrite ^/here/(.*)$ /sets/$1 permanent; }\n }\n"
               " server {\n  listen 127.0.0.1:" + http + ";\n  root " + dir.file("www") + ";\n"
               "  access_log " + dir.file("http.log") + " sent;\n }\n"
               " server {\n  listen 127.0.0.1:" + other + tls + "  root " + dir.file("www") + ";\n"
               "  access_log " + dir.file("other.log") + " sent;\n"
               "  location /locked/ { return 401; }\n }\n";
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string a = "https://127.0.0.1:" + std::to_string(nginx->ports[0]);
    auto view = [&](const std::string& url, std::vector<std::string> extra) {
        std::vector<std::string> args = {binary("surfcast-view"), "--headless", url, "--lod", "1", "--size", "64x48",
                                         "--ca-file", dir.file("ca.pem"), "--token-file", dir.file("token"),
                                         "--header", "X-Api-Key: k3y-secret", "--out", dir.file("x.png")};
        args.insert(args.end(), extra.begin(), extra.end());
        return run(args);
    };
    ASSERT_EQ(view(a + "/sets/scene", {}).exitCode, 0) << "the credentials open A's own set";
    // So they do in the window without --lod, which opens the set once, with
    // them (a second open without them would fail after loading it).
    const size_t before = test::readFile(dir.file("a.log")).size();
    auto window = run({"/usr/bin/xvfb-run", "-a", "-s", "-screen 0 640x480x24", binary("surfcast-view"), a + "/sets/scene",
                       "--size", "64x48", "--frames", "2", "--ca-file", dir.file("ca.pem"), "--token-file", dir.file("token"),
                       "--header", "X-Api-Key: k3y-secret", "--screenshot", dir.file("window.png")});
    EXPECT_EQ(window.exitCode, 0) << window.output;
    EXPECT_TRUE(std::filesystem::exists(dir.file("window.png"))) << window.output;
    std::istringstream requests(test::readFile(dir.file("a.log")).substr(before));
    int tilesetJson = 0;
    for (std::string line; std::getline(requests, line);) tilesetJson += line.find("GET /sets/scene/tileset.json ") != std::string::npos;
    EXPECT_EQ(tilesetJson, 1);

    // A relative Location (a 301 within A): followed, with the credentials.
    auto here = view(a + "/here/scene", {});
    EXPECT_EQ(here.exitCode, 0) << here.output;

    // To another origin: followed, without the credentials.
    auto away = view(a + "/away/scene", {});
    EXPECT_EQ(away.exitCode, 0) << away.output;
    const std::string log = test::readFile(dir.file("other.log"));
    EXPECT_NE(log.find("GET /sets/scene/blocks.bin"), std::string::npos) << log;
    EXPECT_EQ(log.find("s3cret"), std::string::npos) << log;
    EXPECT_EQ(log.find("k3y"), std::string::npos) << log;
    // Another origin that wants credentials: the refusal says why none went.
    auto locked = view(a + "/locked/scene", {});
    EXPECT_EQ(locked.exitCode, 1) << locked.output;
    EXPECT_NE(locked.output.find("HTTP 401: the host refuses access (a redirect led to another origin, which was not sent "
                                 "the credentials: --redirect-credentials sends them)"),
              std::string::npos)
        << locked.output;
    // Opted in: they go along (so the log above would have shown them).
    auto trusted = view(a + "/away/scene", {"--redirect-credentials"});
    EXPECT_EQ(trusted.exitCode, 0) << trusted.output;
    const std::string after = test::readFile(dir.file("other.log")).substr(log.size());
    EXPECT_NE(after.find("auth=\"Bearer s3cret-Token\" key=\"k3y-secret\""), std::string::npos) << after;

    // From https to http, or to another scheme: refused at once, naming both;
    // the http origin never hears of it, opted in or not.
    for (const std::vector<std::string>& extra : {std::vector<std::string>{}, std::vector<std::string>{"--redirect-credentials"}}) {
        auto down = view(a + "/down/scene", extra);
        EXPECT_EQ(down.exitCode, 1) << down.output;
        EXPECT_NE(down.output.find(a + "/down/scene/tileset.json: redirected to http://127.0.0.1:" +
                                   std::to_string(nginx->ports[1]) + "/sets/scene/tileset.json, which is not followed: "
                                   "https never gives way to plain http"), std::string::npos)
            << down.output;
    }
    EXPECT_FALSE(std::filesystem::exists(dir.file("http.log")) && std::filesystem::file_size(dir.file("http.log")) > 0)
        << test::readFile(dir.file("http.log"));
    auto ftp = view(a + "/ftp/scene", {});
    EXPECT_EQ(ftp.exitCode, 1) << ftp.output;
    EXPECT_NE(ftp.output.find("which is not followed: only http and https are"), std::string::npos) << ftp.output;
}

// surfcast-serve --tls-cert/--tls-key --token-file: HTTPS from libmicrohttpd
// (GnuTLS), batches included, behind a bearer token; with the token the
// streamed image equals the folder's, without it 401 names the URL. A
// certificate the client does not trust fails at once; a key that is not the
// certificate's stops the server with a clear message.
TEST(Stream, SurfcastServeOverHttpsWithAToken) {
    TempDir dir;
    std::filesystem::create_directories(dir.file("sets"));
    auto b = test::buildScene(dir.file("sets/scene"), 100000, {"--capacity", "3000"});
    ASSERT_EQ(b.exitCode, 0) << b.output;
    makeCertificates(dir);
    test::writeFile(dir.file("token"), "s3cret-Token\n");
    test::Child server;
    const std::string origin =
        test::startServer(&server, dir.file("sets"), "127.0.0.1:0",
                          {"--tls-cert", dir.file("server.pem"), "--tls-key", dir.file("server.key"), "--token-file", dir.file("token")});
    ASSERT_EQ(origin.rfind("https://127.0.0.1:", 0), 0u) << server.log;
    auto last = expectStreamsLikeLocal(origin + "/sets/scene", dir.file("sets/scene"), "--camera=3,-6,2,0,0,0.5,0,0,1,50",
                                       dir, {"--ca-file", dir.file("ca.pem"), "--token-file", dir.file("token")});
    EXPECT_EQ(last.dump().find("s3cret"), std::string::npos);
    auto refused = run({binary("surfcast-view"), "--headless", origin + "/sets/scene", "--lod", "1", "--size", "64x48",
                        "--ca-file", dir.file("ca.pem"), "--out", dir.file("x.png")});
    EXPECT_NE(refused.exitCode, 0);
    EXPECT_NE(refused.output.find(origin + "/sets/scene/tileset.json: HTTP 401"), std::string::npos) << refused.output;
    auto untrusted = run({binary("surfcast-view"), "--headless", origin + "/sets/scene", "--lod", "1", "--size", "64x48",
                          "--ca-file", dir.file("other.pem"), "--out", dir.file("x.png")});
    EXPECT_NE(untrusted.exitCode, 0);
    EXPECT_NE(untrusted.output.find("TLS with the host failed"), std::string::npos) << untrusted.output;
    ::kill(server.pid, SIGTERM);
    EXPECT_EQ(test::exitCode(server.pid), 0) << server.log;

    auto mismatched = run({binary("surfcast-serve"), dir.file("sets"), "--bind", "127.0.0.1:0", "--tls-cert",
                           dir.file("server.pem"), "--tls-key", dir.file("ca.key")});
    EXPECT_EQ(mismatched.exitCode, 1);
    EXPECT_NE(mismatched.output.find("the TLS certificate and key do not load"), std::string::npos) << mismatched.output;
    auto alone = run({binary("surfcast-serve"), dir.file("sets"), "--tls-cert", dir.file("server.pem")});
    EXPECT_EQ(alone.exitCode, 2);
    EXPECT_NE(alone.output.find("--tls-cert and --tls-key go together"), std::string::npos) << alone.output;
}

// Inputs at URLs (preprocess/readers/input_file.h): nginx serving the shared
// scans as static files. A PCD, a COPC and a LAS file by URL, staged in four
// parts (the COPC file cut at a chunk and the LAS file at 65,536 records, each
// part reading its run by ranges), write the same bytes as one build of the
// same files by path (under TSan: one build by URL, in one process). A
// presigned URL (a query string the host checks) is read, and its query shows
// in no message, plan or record. A missing file, a URL with a user name, and
// a mesh by URL each fail with the URL and why.
TEST(Inputs, ReadFromUrlsByRangesSameBytesAsLocalFiles) {
    REQUIRE_DATA();
    TempDir dir;
    const std::string data = std::filesystem::path(test::dataFile("lion_takanawa.copc.laz")).parent_path().string();
    auto nginx = startNginx(dir.file("nginx"), 1, [&](const std::vector<int>& ports) {
        return " server { listen 127.0.0.1:" + std::to_string(ports[0]) + "; location /scans/ { alias " + data +
               "/; } location /signed/ { if ($arg_sig != \"secret\") { return 403; } alias " + data + "/; } }\n";
    });
    ASSERT_FALSE(nginx->ports.empty());
    const std::string url = "http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/scans/";
    const std::vector<std::string> files = {"fragment.pcd", "lion_takanawa.copc.laz", "autzen_trim.las"};
    const std::vector<std::string> options = {"-q", "--memory", "128M", "--capacity", "4000"};
    std::vector<std::string> remote = options;
    for (const std::string& f : files) remote.push_back(url + f);
    remote.insert(remote.end(), {"-o", dir.file("remote")});
#if defined(SURFCAST_TSAN)
    // Under ThreadSanitizer the URLs' fetch threads are those of one process,
    // and what it checks is their synchronization: the staged parts (range
    // reads from within a file) and the bytes against the build by path run
    // in the other stages (bench/RELIABILITY.md, "What each CI stage covers").
    remote.insert(remote.begin(), binary("surfcast-build"));
    auto whole = run(remote);
    ASSERT_EQ(whole.exitCode, 0) << whole.output;
    EXPECT_TRUE(std::filesystem::exists(dir.file("remote/tileset.json"))) << whole.output;
#else
    std::vector<std::string> local = {binary("surfcast-build")};
    local.insert(local.end(), options.begin(), options.end());
    for (const std::string& f : files) local.push_back(data + "/" + f);
    local.insert(local.end(), {"-o", dir.file("local")});
    auto one = run(local);
    ASSERT_EQ(one.exitCode, 0) << one.output;
    const std::string work = dir.file("work");
    auto stage = [&](std::vector<std::string> args, const std::vector<std::string>& more = {}) {
        args.insert(args.begin(), binary("surfcast-build"));
        args.insert(args.end(), more.begin(), more.end());
        auto r = run(args);
        EXPECT_EQ(r.exitCode, 0) << r.output;
        return r.exitCode == 0;
    };
    for (const char* name : {"scan", "count"})
        for (int p = 0; p < 4; ++p) ASSERT_TRUE(stage({name, "--work", work, "--part", std::to_string(p) + "/4"}, remote));
    ASSERT_TRUE(stage({"plan", "--work", work, "--parts", "4"}, remote));
    const std::string json = test::readFile(work + "/plan.json");
    EXPECT_NE(json.find("\"first\": 1, \"begin\": 0, \"last\": 1, \"end\": "), std::string::npos) << "a part should end within the COPC file: " << json;
    EXPECT_NE(json.find("\"last\": 2, \"end\": 65536"), std::string::npos) << "a part should end within the LAS file: " << json;
    for (int p = 0; p < 4; ++p) ASSERT_TRUE(stage({"distribute", "--work", work, "-q", "--part", std::to_string(p)}));
    const size_t chunks = std::stoul(json.substr(json.find("\"chunks\": ") + 10));
    for (size_t i = 0; i < chunks; ++i) ASSERT_TRUE(stage({"chunk", "--work", work, "-q", std::to_string(i)}));
    ASSERT_TRUE(stage({"merge", "--work", work, "-q"}));
    for (const char* f : {"tileset.json", "hierarchy.bin", "blocks.bin"})
        EXPECT_TRUE(test::readFile(dir.file("local/") + f) == test::readFile(dir.file("remote/") + f)) << f;
#endif

    // A presigned URL: read with its query, which shows nowhere.
    const std::string signedUrl = "http://127.0.0.1:" + std::to_string(nginx->ports[0]) + "/signed/fragment.pcd";
    // A header (a token) is no more stored than the query.
    auto presigned = run({binary("surfcast-build"), "-q", signedUrl + "?sig=secret", "--header", "X-Token: header-secret", "-o", dir.file("signed")});
    ASSERT_EQ(presigned.exitCode, 0) << presigned.output;
    EXPECT_EQ(presigned.output.find("secret"), std::string::npos) << presigned.output;
    EXPECT_EQ(test::readFile(dir.file("signed/build.bin")).find("secret"), std::string::npos) << "the build record holds the query or header";
    auto planned = run({binary("surfcast-build"), "plan", "--work", dir.file("signed-work"), "-q", signedUrl + "?sig=secret", "--header",
                        "X-Token: header-secret", "-o", dir.file("x")});
    ASSERT_EQ(planned.exitCode, 0) << planned.output;
    const std::string plan = test::readFile(dir.file("signed-work/plan.json")) + test::readFile(dir.file("signed-work/plan.bin"));
    EXPECT_EQ(plan.find("secret"), std::string::npos) << "the plan holds the query or header";
    EXPECT_NE(plan.find("/signed/fragment.pcd?"), std::string::npos) << "the plan names the input, its query redacted";
    // A stage in another process never saw the query: it says so. (It takes
    // how to reach URLs on its own command line: never from the plan.)
    auto later = run({binary("surfcast-build"), "distribute", "--work", dir.file("signed-work"), "-q", "--part", "0", "--header",
                      "X-Token: header-secret"});
    EXPECT_EQ(later.exitCode, 1) << later.output;
    EXPECT_NE(later.output.find("kept in memory only"), std::string::npos) << later.output;

    // Clear errors, and no set written.
    const std::pair<std::string, std::string> bad[] = {
        {url + "missing.laz", url + "missing.laz: HTTP 404"},
        {url + "missing.laz?sig=secret", url + "missing.laz: HTTP 404"},
        {signedUrl + "?sig=wrong-secret", "/signed/fragment.pcd: HTTP 403"},
        {"http://user:secret@" + url.substr(7) + "lone-star.laz", "a user name or password is not taken"},
        {url + "fg_spkMgDragon/fg_spkMgDragon.obj", "meshes are read from local files only"},
    };
    for (const auto& [input, message] : bad) {
        auto r = run({binary("surfcast-build"), "-q", input, "-o", dir.file("bad")});
        EXPECT_EQ(r.exitCode, 1) << input << ": " << r.output;
        EXPECT_NE(r.output.find(message), std::string::npos) << input << ": " << r.output;
        EXPECT_EQ(r.output.find("secret"), std::string::npos) << "the query string shows: " << r.output;
        EXPECT_FALSE(std::filesystem::exists(dir.file("bad")));
    }
}

}  // namespace
}  // namespace surfcast
