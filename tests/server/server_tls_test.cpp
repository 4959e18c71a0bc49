// wss://: a server with a certificate (a self-signed one made here with the openssl tool for
// 127.0.0.1 and localhost) serves the same protocol over TLS; a client verifies the certificate
// (against the CA file it is given, else the system's store, which does not hold ours) and its
// name; a plain ws:// client against the TLS port fails without harming the server.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include "server_test_util.hpp"

namespace deepcanvas::test {
namespace {

namespace fs = std::filesystem;

struct CertFiles {
  std::string cert, key;
};

// This process's folder for certificates, removed at exit.
const fs::path& cert_dir() {
  static const struct Dir {
    fs::path path =
        fs::path(testing::TempDir()) / ("deepcanvas_tls_" + std::to_string(std::random_device{}()));
    Dir() { fs::create_directories(path); }
    ~Dir() {
      std::error_code ec;
      fs::remove_all(path, ec);
    }
  } dir;
  return dir.path;
}

// A fresh self-signed certificate (RSA 2048, one day) naming `names` in its subjectAltName.
CertFiles make_cert(const std::string& stem, const std::string& names) {
  const fs::path& dir = cert_dir();
  CertFiles f{(dir / (stem + "_cert.pem")).string(), (dir / (stem + "_key.pem")).string()};
  const std::string cmd =
      "openssl req -x509 -newkey rsa:2048 -nodes -subj /CN=localhost "
      "-addext subjectAltName=" +
      names + " -days 1 -keyout '" + f.key + "' -out '" + f.cert + "' >/dev/null 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  return f;
}

const CertFiles& local_cert() {
  static const CertFiles f = make_cert("local", "IP:127.0.0.1,DNS:localhost");
  return f;
}

TestServer start_tls_server(const CertFiles& f) {
  return start_server({"c"}, "", {}, 0, [&](server_net::ServerConfig& cfg) {
    cfg.tls_cert_file = f.cert;
    cfg.tls_key_file = f.key;
  });
}

std::string wss_url(const TestServer& s, const std::string& host = "127.0.0.1") {
  return "wss://" + host + ":" + std::to_string(s.server->port()) + "/";
}

// Paints one stroke and waits for its ack (and for the canvas to reach the client).
void paint_one(client_core::Client& c) {
  std::mt19937_64 rng(26);
  auto h = c.send_stroke(random_stroke(rng));
  ASSERT_TRUE(h.ok()) << h.error().message;
  auto ack = c.wait_for_ack(*h, 30s);
  ASSERT_TRUE(ack.ok()) << ack.error().message;
  EXPECT_EQ(ack->handle, *h);
}

TEST(ServerTls, PaintsOverWssWithTheCaFile) {
  auto s = start_tls_server(local_cert());
  ASSERT_TRUE(s.server);
  for (const std::string host : {"127.0.0.1", "localhost"}) {
    auto o = client_options(s);
    o.url = wss_url(s, host);
    o.ca_file = local_cert().cert;
    auto c = client_core::Client::connect(o);
    ASSERT_TRUE(c.ok()) << host << ": " << c.error().message;
    paint_one(**c);
    ASSERT_TRUE((*c)->wait_for_epoch(1, 30s).ok());
    expect_converged(*s.canvas(), {c->get()});
  }
}

TEST(ServerTls, ClientWithoutTheCaGetsACertificateError) {
  auto s = start_tls_server(local_cert());
  ASSERT_TRUE(s.server);
  auto o = client_options(s);
  o.url = wss_url(s);  // verified against the system's store, which does not hold this one
  auto c = client_core::Client::connect(o);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, Errc::io_error);
  EXPECT_NE(c.error().message.find("certificate"), std::string::npos) << c.error().message;
  EXPECT_NE(c.error().message.find("TLS handshake"), std::string::npos) << c.error().message;
}

TEST(ServerTls, CertificateForAnotherNameIsRefused) {
  const auto other = make_cert("other", "DNS:example.invalid");
  auto s = start_tls_server(other);
  ASSERT_TRUE(s.server);
  auto o = client_options(s);
  o.url = wss_url(s);
  o.ca_file = other.cert;  // trusted, but it does not name 127.0.0.1
  auto c = client_core::Client::connect(o);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.error().code, Errc::io_error);
  EXPECT_NE(c.error().message.find("certificate"), std::string::npos) << c.error().message;
}

TEST(ServerTls, PlainClientAgainstTheTlsPortFailsCleanly) {
  auto s = start_tls_server(local_cert());
  ASSERT_TRUE(s.server);
  auto o = client_options(s);
  o.connect_timeout = 10s;
  auto plain = client_core::Client::connect(o);  // ws:// on the TLS port
  ASSERT_FALSE(plain.ok());
  EXPECT_EQ(plain.error().code, Errc::io_error) << plain.error().message;
  // Plain HTTP gets no answer either (http_get returns status 0 on a dropped connection).
  EXPECT_NE(http_get(s, "/healthz").first, 200);
  // The server is unharmed: a TLS client paints.
  o.url = wss_url(s);
  o.ca_file = local_cert().cert;
  auto c = client_core::Client::connect(o);
  ASSERT_TRUE(c.ok()) << c.error().message;
  paint_one(**c);
}

TEST(ServerTls, BadFilesAreRefusedNamingTheFile) {
  auto create = [](const std::string& cert, const std::string& key) {
    server_net::ServerConfig cfg;
    cfg.port = 0;
    cfg.canvases.push_back(small_canvas("c"));
    cfg.tls_cert_file = cert;
    cfg.tls_key_file = key;
    return server_net::Server::create(std::move(cfg));
  };
  const auto& good = local_cert();
  const auto other = make_cert("mismatch", "DNS:localhost");
  const std::string missing = (fs::path(testing::TempDir()) / "no_such_cert.pem").string();
  struct Case {
    std::string cert, key, named;
  };
  for (const Case& k : {Case{missing, good.key, missing}, Case{good.cert, missing, missing},
                        Case{good.key, good.key, good.key},  // a key is not a certificate
                        Case{good.cert, other.key, other.key}, Case{good.cert, "", "key"},
                        Case{"", good.key, "certificate"}}) {
    auto r = create(k.cert, k.key);
    ASSERT_FALSE(r.ok()) << k.cert << " / " << k.key;
    EXPECT_EQ(r.error().code, Errc::invalid_argument);
    EXPECT_NE(r.error().message.find(k.named), std::string::npos) << r.error().message;
  }
}

}  // namespace
}  // namespace deepcanvas::test
