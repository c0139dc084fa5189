#pragma once
// The lens-shifter controller on a serial port (termios, raw 8N1).
//
// Line protocol: ASCII, one command per line ending in '\n' (a '\r' before it is ignored), one
// reply line per command. Positions are absolute, in motor steps (session.json shift_steps).
//   "ID?"           -> "OK <identification text>"
//   "POS?"          -> "OK <pos>"
//   "MOVE <steps>"  -> "OK <pos>"   absolute move; the reply comes when the motor has stopped
//   "HOME"          -> "OK <pos>"   drive to the reference switch, which is position 0
//   any failure     -> "ERR <message>" (e.g. "ERR out of range", "ERR unknown command")
// Every wait has a deadline: a silent, half-answering or unplugged controller throws
// Error(kDevice) naming the port, never hangs.

#include <array>
#include <filesystem>
#include <string>
#include <vector>

namespace mesoscan {

struct LensShifterOptions {
  std::string port;                             // serial device, e.g. /dev/ttyUSB0 or a pty
  int baud = 115200;                            // 9600, 19200, 38400, 57600, 115200 or 230400
  double reply_timeout_s = 2.0;                 // > 0; deadline for a reply to ID?, POS?
  double move_timeout_s = 30.0;                 // > 0; deadline for the reply to MOVE and HOME
  std::array<int, 2> range_steps{-2048, 2048};  // moves outside are refused before sending
  void Check() const;
};

class LensShifterController {
 public:
  // Opens and configures the port, then asks "ID?" to make sure a controller answers.
  explicit LensShifterController(const LensShifterOptions& options);
  ~LensShifterController();
  LensShifterController(const LensShifterController&) = delete;
  LensShifterController& operator=(const LensShifterController&) = delete;

  const std::string& id() const { return id_; }
  int Position();
  // Absolute move; returns the position the controller reports after the move.
  int MoveTo(int steps);
  int Home();

  // Sends one command line and returns the text after "OK " (throws on ERR or timeout).
  std::string Command(const std::string& line, double timeout_s);

 private:
  int ParsePosition(const std::string& command, const std::string& reply) const;
  [[noreturn]] void Fail(const std::string& what) const;

  LensShifterOptions options_;
  int fd_ = -1;
  std::string id_;
  std::string pending_;  // bytes received after the last complete line
};

// Serial ports present under dev_root: ttyUSB*, ttyACM* and serial/by-id/* (sorted).
std::vector<std::string> ListSerialPorts(const std::filesystem::path& dev_root = "/dev");

}  // namespace mesoscan
