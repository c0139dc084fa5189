#include "capture/lens_shifter_sim.h"

#include <fcntl.h>
#include <poll.h>
#include <stdlib.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>

#include "core/error.h"

namespace mesoscan {

LensShifterSim::LensShifterSim(const LensShifterSimOptions& options) : options_(options) {
  MESOSCAN_CHECK_LT(options_.range_steps[0], options_.range_steps[1]);
  MESOSCAN_CHECK(options_.steps_per_second > 0);
  master_ = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (master_ < 0 || grantpt(master_) != 0 || unlockpt(master_) != 0)
    MESOSCAN_THROW(ErrorKind::kDevice, "lens-shifter simulator: cannot create a pseudo-terminal ("
                                           << std::strerror(errno) << ")");
  char name[128];
  if (ptsname_r(master_, name, sizeof(name)) != 0)
    MESOSCAN_THROW(ErrorKind::kDevice, "lens-shifter simulator: ptsname failed");
  port_ = name;
  // Hold the slave open in raw mode: no echo of our replies back to us before a client has
  // configured the line, and no POLLHUP on the master while no client is connected.
  slave_ = ::open(port_.c_str(), O_RDWR | O_NOCTTY | O_CLOEXEC);
  if (slave_ < 0)
    MESOSCAN_THROW(ErrorKind::kDevice, "lens-shifter simulator: cannot open "
                                           << port_ << " (" << std::strerror(errno) << ")");
  termios tio{};
  tcgetattr(slave_, &tio);
  cfmakeraw(&tio);
  tcsetattr(slave_, TCSANOW, &tio);
  thread_ = std::thread([this] { Run(); });
}

LensShifterSim::~LensShifterSim() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (master_ >= 0) ::close(master_);
  if (slave_ >= 0) ::close(slave_);
}

void LensShifterSim::InjectError(const std::string& message) { InjectReply("ERR " + message); }

void LensShifterSim::InjectRaw(const std::string& bytes) {
  std::lock_guard<std::mutex> lock(inject_mutex_);
  inject_ = bytes;
}

void LensShifterSim::Close() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  if (master_ >= 0) ::close(master_);
  master_ = -1;
  if (slave_ >= 0) ::close(slave_);
  slave_ = -1;
}

std::string LensShifterSim::Answer(const std::string& line) {
  const auto reply = [&](const std::string& text) -> std::string { return text + "\n"; };
  {
    std::lock_guard<std::mutex> lock(inject_mutex_);
    if (!inject_.empty()) {
      std::string r = inject_;
      inject_.clear();
      return r;
    }
  }
  const auto move = [&](int target) {
    const double seconds = std::abs(target - position_) / options_.steps_per_second;
    // Sleep in slices so that the destructor is never held up by a long simulated move.
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (!stop_ && std::chrono::steady_clock::now() < end)
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    position_ = target;
    return reply("OK " + std::to_string(target));
  };
  if (line == "ID?") return reply("OK " + options_.id);
  if (line == "POS?") return reply("OK " + std::to_string(position_));
  if (line == "HOME") return move(0);
  if (line.rfind("MOVE ", 0) == 0) {
    const std::string arg = line.substr(5);
    size_t used = 0;
    long target = 0;
    try {
      target = std::stol(arg, &used);
    } catch (const std::exception&) {
      return reply("ERR bad argument");
    }
    if (used != arg.size()) return reply("ERR bad argument");
    if (target < options_.range_steps[0] || target > options_.range_steps[1])
      return reply("ERR out of range");
    return move(static_cast<int>(target));
  }
  return reply("ERR unknown command");
}

void LensShifterSim::Run() {
  std::string buffer;
  while (!stop_) {
    pollfd p{master_, POLLIN, 0};
    const int r = ::poll(&p, 1, 20);
    if (r <= 0 || !(p.revents & POLLIN)) continue;
    char buf[256];
    const ssize_t n = ::read(master_, buf, sizeof(buf));
    if (n <= 0) continue;
    buffer.append(buf, static_cast<size_t>(n));
    size_t nl;
    while ((nl = buffer.find('\n')) != std::string::npos) {
      std::string line = buffer.substr(0, nl);
      buffer.erase(0, nl + 1);
      if (!line.empty() && line.back() == '\r') line.pop_back();
      ++commands_;
      if (mute_) continue;
      const std::string reply = Answer(line);
      size_t sent = 0;
      while (sent < reply.size() && !stop_) {
        const ssize_t w = ::write(master_, reply.data() + sent, reply.size() - sent);
        if (w > 0)
          sent += static_cast<size_t>(w);
        else if (errno != EAGAIN && errno != EINTR)
          break;
      }
    }
  }
}

}  // namespace mesoscan
