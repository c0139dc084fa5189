#include "capture/lens_shifter.h"

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>

#include "core/error.h"

namespace mesoscan {
namespace fs = std::filesystem;

namespace {

speed_t BaudConstant(int baud) {
  switch (baud) {
    case 9600:
      return B9600;
    case 19200:
      return B19200;
    case 38400:
      return B38400;
    case 57600:
      return B57600;
    case 115200:
      return B115200;
    case 230400:
      return B230400;
  }
  return B0;
}

// Device text made safe for a one-line message: printable ASCII, at most 60 characters.
std::string Clean(const std::string& s) {
  std::string t;
  for (char c : s.substr(0, 60)) t += (c >= 32 && c < 127) ? c : '?';
  return s.size() > 60 ? t + "..." : t;
}

std::string Printable(const std::string& s) {
  std::string quoted(1, '"');  // built by append: GCC 12 warns (-Wrestrict) on "\"" + s + "\""
  quoted += Clean(s);
  quoted += '"';
  return quoted;
}

std::string Seconds(double s) {
  std::ostringstream oss;
  oss << s;
  return oss.str();
}

}  // namespace

void LensShifterOptions::Check() const {
  if (port.empty()) MESOSCAN_BAD_INPUT("lens shifter: port: expected a serial device path");
  if (BaudConstant(baud) == B0)
    MESOSCAN_BAD_INPUT(
        "lens shifter: baud: expected 9600, 19200, 38400, 57600, 115200 or 230400, got " << baud);
  if (!(reply_timeout_s > 0) || !(move_timeout_s > 0))
    MESOSCAN_BAD_INPUT("lens shifter: timeouts: expected > 0 s");
  if (range_steps[0] >= range_steps[1])
    MESOSCAN_BAD_INPUT("lens shifter: range_steps: expected [min, max] with min < max");
}

LensShifterController::LensShifterController(const LensShifterOptions& options)
    : options_(options) {
  options_.Check();
  // Non-blocking so that open() never waits for modem lines and reads are bounded by poll().
  fd_ = ::open(options_.port.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) Fail(std::string("cannot open (") + std::strerror(errno) + ")");
  termios tio{};
  if (tcgetattr(fd_, &tio) != 0) {
    const int e = errno;
    ::close(fd_);
    fd_ = -1;
    Fail(std::string("not a serial port (") + std::strerror(e) + ")");
  }
  cfmakeraw(&tio);  // 8N1, no echo, no line editing, no CR/LF translation
  tio.c_cflag |= CLOCAL | CREAD;
  tio.c_cflag &= ~CRTSCTS;
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  cfsetispeed(&tio, BaudConstant(options_.baud));
  cfsetospeed(&tio, BaudConstant(options_.baud));
  if (tcsetattr(fd_, TCSANOW, &tio) != 0) {
    const int e = errno;
    ::close(fd_);
    fd_ = -1;
    Fail(std::string("cannot configure (") + std::strerror(e) + ")");
  }
  tcflush(fd_, TCIOFLUSH);
  try {
    id_ = Command("ID?", options_.reply_timeout_s);
  } catch (...) {
    ::close(fd_);
    fd_ = -1;
    throw;
  }
}

LensShifterController::~LensShifterController() {
  if (fd_ >= 0) ::close(fd_);
}

void LensShifterController::Fail(const std::string& what) const {
  MESOSCAN_THROW(ErrorKind::kDevice, options_.port << ": " << what);
}

std::string LensShifterController::Command(const std::string& line, double timeout_s) {
  using Clock = std::chrono::steady_clock;
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(timeout_s));
  // A late reply to an earlier, timed-out command must not answer this one.
  tcflush(fd_, TCIFLUSH);
  pending_.clear();

  const std::string out = line + "\n";
  size_t sent = 0;
  while (sent < out.size()) {
    const ssize_t n = ::write(fd_, out.data() + sent, out.size() - sent);
    if (n > 0) {
      sent += static_cast<size_t>(n);
      continue;
    }
    if (n < 0 && (errno == EIO || errno == ENXIO || errno == EPIPE || errno == ENODEV))
      Fail("connection closed while sending " + Printable(line));  // unplugged USB adapter
    if (n < 0 && errno != EAGAIN && errno != EINTR)
      Fail(line + ": write failed (" + std::strerror(errno) + ")");
    const int ms = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count());
    if (ms <= 0) Fail(line + ": cannot send within " + Seconds(timeout_s) + " s");
    pollfd p{fd_, POLLOUT, 0};
    ::poll(&p, 1, ms);
  }

  // Read until a complete line or the deadline.
  std::string reply;
  for (;;) {
    const size_t nl = pending_.find('\n');
    if (nl != std::string::npos) {
      reply = pending_.substr(0, nl);
      pending_.erase(0, nl + 1);
      if (!reply.empty() && reply.back() == '\r') reply.pop_back();
      if (reply.empty()) continue;  // blank keep-alive lines are ignored
      break;
    }
    const int ms = static_cast<int>(
        std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now()).count());
    if (ms <= 0)
      Fail("no reply to " + Printable(line) + " within " + Seconds(timeout_s) + " s" +
           (pending_.empty() ? "" : " (partial: " + Printable(pending_) + ")"));
    pollfd p{fd_, POLLIN, 0};
    const int r = ::poll(&p, 1, ms);
    if (r < 0 && errno != EINTR) Fail(std::string("poll failed (") + std::strerror(errno) + ")");
    if (r <= 0) continue;
    if (p.revents & (POLLHUP | POLLERR | POLLNVAL)) {
      // Drain what is left before declaring the line dead.
      char buf[256];
      const ssize_t n = ::read(fd_, buf, sizeof(buf));
      if (n > 0) {
        pending_.append(buf, static_cast<size_t>(n));
        continue;
      }
      Fail("connection closed while waiting for the reply to " + Printable(line));
    }
    char buf[256];
    const ssize_t n = ::read(fd_, buf, sizeof(buf));
    if (n > 0) {
      pending_.append(buf, static_cast<size_t>(n));
      if (pending_.size() > 4096) Fail("reply to " + Printable(line) + " too long (no newline)");
    } else if (n == 0 || (errno != EAGAIN && errno != EINTR)) {
      Fail("connection closed while waiting for the reply to " + Printable(line));
    }
  }
  if (reply.rfind("ERR", 0) == 0) {
    Fail(line +
         ": controller error: " + (reply.size() > 4 ? Clean(reply.substr(4)) : "(no message)"));
  }
  if (reply == "OK") return "";
  if (reply.rfind("OK ", 0) != 0)
    Fail("unexpected reply " + Printable(reply) + " to " + Printable(line));
  return reply.substr(3);
}

int LensShifterController::ParsePosition(const std::string& command,
                                         const std::string& reply) const {
  try {
    size_t used = 0;
    const long v = std::stol(reply, &used);
    if (used == reply.size() && v >= std::numeric_limits<int>::min() &&
        v <= std::numeric_limits<int>::max())
      return static_cast<int>(v);
  } catch (const std::exception&) {
  }
  Fail("unexpected reply " + Printable("OK " + reply) + " to " + Printable(command) +
       ", expected \"OK <steps>\"");
}

int LensShifterController::Position() {
  return ParsePosition("POS?", Command("POS?", options_.reply_timeout_s));
}

int LensShifterController::MoveTo(int steps) {
  if (steps < options_.range_steps[0] || steps > options_.range_steps[1])
    MESOSCAN_BAD_INPUT(options_.port << ": MOVE " << steps << ": outside range_steps ["
                                     << options_.range_steps[0] << ", " << options_.range_steps[1]
                                     << "]");
  const std::string cmd = "MOVE " + std::to_string(steps);
  const int pos = ParsePosition(cmd, Command(cmd, options_.move_timeout_s));
  if (pos != steps)
    Fail(cmd + ": controller reports position " + std::to_string(pos) + " after the move");
  return pos;
}

int LensShifterController::Home() {
  return ParsePosition("HOME", Command("HOME", options_.move_timeout_s));
}

std::vector<std::string> ListSerialPorts(const fs::path& dev_root) {
  std::vector<std::string> ports;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(dev_root, ec)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("ttyUSB", 0) == 0 || name.rfind("ttyACM", 0) == 0)
      ports.push_back(e.path().string());
  }
  for (const auto& e : fs::directory_iterator(dev_root / "serial" / "by-id", ec))
    ports.push_back(e.path().string());
  std::sort(ports.begin(), ports.end());
  return ports;
}

}  // namespace mesoscan
