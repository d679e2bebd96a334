//! `kairos devices`: the serial ports, CAN interfaces and cameras of this machine, found where Linux lists
//! them (`/dev`, `/dev/serial/by-id`, `/sys/class/net`, `/sys/class/video4linux`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub use kairos_protocol::DeviceInfo as Device;
use kairos_sdk_core::DeviceKind;

/// The devices under `root` (`/` but in tests), serial ports first, each kind by path.
pub fn list(root: &Path) -> Vec<Device> {
    let mut devices = serial_ports(root);
    devices.extend(can_interfaces(root));
    devices.extend(cameras(root));
    devices
}

fn entries(folder: &Path) -> Vec<PathBuf> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(folder)
        .map(|entries| entries.filter_map(Result::ok).map(|e| e.path()).collect())
        .unwrap_or_default();
    paths.sort();
    paths
}

fn name_of(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn read_trimmed(path: &Path) -> Option<String> {
    std::fs::read_to_string(path)
        .ok()
        .map(|text| text.trim().to_owned())
}

/// Device names of serial ports that are there only when their hardware is: USB adapters (FTDI and the
/// like, CDC-ACM), the UARTs of ARM boards, Bluetooth serial. (`ttyS*` exist whether or not a port does.)
const SERIAL_PREFIXES: [&str; 6] = ["ttyUSB", "ttyACM", "ttyAMA", "ttyTHS", "ttymxc", "rfcomm"];

/// USB serial adapters and on-board UARTs with a driver: `/dev/serial/by-id` names what they are.
fn serial_ports(root: &Path) -> Vec<Device> {
    let dev = root.join("dev");
    let mut ports: Vec<Device> = Vec::new();
    // The stable names first: what each adapter is, and the port it points to.
    for link in entries(&dev.join("serial/by-id")) {
        let Ok(target) = std::fs::read_link(&link) else {
            continue;
        };
        let port = name_of(&target);
        let description = name_of(&link)
            .trim_start_matches("usb-")
            .rsplit_once("-if")
            .map_or_else(|| name_of(&link), |(name, _)| name.to_owned())
            .replace('_', " ");
        ports.push(Device {
            kind: DeviceKind::Serial,
            path: format!("/dev/{port}"),
            description: format!(
                "{description} ({})",
                link.display()
                    .to_string()
                    .replacen(&root.display().to_string(), "", 1)
            ),
        });
    }
    for path in entries(&dev) {
        let name = name_of(&path);
        let known = ports.iter().any(|p| p.path == format!("/dev/{name}"));
        if !known && SERIAL_PREFIXES.iter().any(|prefix| name.starts_with(prefix)) {
            ports.push(Device {
                kind: DeviceKind::Serial,
                path: format!("/dev/{name}"),
                description: "serial port".to_owned(),
            });
        }
    }
    ports.sort_by(|a, b| a.path.cmp(&b.path));
    ports
}

/// Network interfaces of type 280 (`ARPHRD_CAN`): `SocketCAN` buses, real or virtual.
fn can_interfaces(root: &Path) -> Vec<Device> {
    entries(&root.join("sys/class/net"))
        .into_iter()
        .filter(|interface| read_trimmed(&interface.join("type")).as_deref() == Some("280"))
        .map(|interface| Device {
            kind: DeviceKind::Can,
            path: name_of(&interface),
            description: format!(
                "CAN interface, {}",
                read_trimmed(&interface.join("operstate")).unwrap_or_else(|| "state unknown".to_owned())
            ),
        })
        .collect()
}

/// Video capture devices (V4L2).
fn cameras(root: &Path) -> Vec<Device> {
    entries(&root.join("sys/class/video4linux"))
        .into_iter()
        .map(|device| Device {
            kind: DeviceKind::Camera,
            path: format!("/dev/{}", name_of(&device)),
            description: read_trimmed(&device.join("name")).unwrap_or_else(|| "video device".to_owned()),
        })
        .collect()
}

/// The devices as text for people: one line each, or a sentence saying none were found and where the
/// search looked.
pub fn text(devices: &[Device]) -> String {
    if devices.is_empty() {
        return "no serial port, CAN interface or camera found (looked in /dev, /dev/serial/by-id, \
                /sys/class/net and /sys/class/video4linux)\n"
            .to_owned();
    }
    let width = devices.iter().map(|d| d.path.len()).max().unwrap_or(0);
    let mut text = String::new();
    for device in devices {
        let _ = writeln!(
            text,
            "{:<6}  {:<width$}  {}",
            device.kind, device.path, device.description
        );
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn serial_ports_can_interfaces_and_cameras_are_found_where_linux_lists_them() {
        let root = tempfile::tempdir().unwrap();
        let dev = root.path().join("dev");
        std::fs::create_dir_all(dev.join("serial/by-id")).unwrap();
        for name in ["ttyUSB0", "ttyACM1", "ttyS0", "null", "video0"] {
            std::fs::write(dev.join(name), "").unwrap();
        }
        std::os::unix::fs::symlink(
            "../../ttyUSB0",
            dev.join("serial/by-id/usb-FTDI_FT232R_USB_UART_A5XK3RJT-if00-port0"),
        )
        .unwrap();
        let net = root.path().join("sys/class/net");
        for (name, kind, state) in [("can0", "280", "up"), ("eth0", "1", "up")] {
            std::fs::create_dir_all(net.join(name)).unwrap();
            std::fs::write(net.join(name).join("type"), format!("{kind}\n")).unwrap();
            std::fs::write(net.join(name).join("operstate"), format!("{state}\n")).unwrap();
        }
        let video = root.path().join("sys/class/video4linux/video0");
        std::fs::create_dir_all(&video).unwrap();
        std::fs::write(video.join("name"), "UVC Camera (046d:0825)\n").unwrap();

        let devices = list(root.path());
        let summary: Vec<(&str, &str)> = devices.iter().map(|d| (d.kind.name(), d.path.as_str())).collect();
        assert_eq!(
            summary,
            [
                ("serial", "/dev/ttyACM1"),
                ("serial", "/dev/ttyUSB0"),
                ("can", "can0"),
                ("camera", "/dev/video0"),
            ]
        );
        assert!(
            devices[1]
                .description
                .starts_with("FTDI FT232R USB UART A5XK3RJT"),
            "{devices:?}"
        );
        assert_eq!(devices[2].description, "CAN interface, up");
        assert_eq!(devices[3].description, "UVC Camera (046d:0825)");
        assert!(text(&devices).contains("/dev/ttyUSB0"));
        assert!(text(&[]).contains("no serial port"));
    }
}
