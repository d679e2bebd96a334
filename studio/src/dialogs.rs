//! The small dialogs: connecting to a remote runtime, and unsaved changes. Each shows while its state is
//! there and pushes [`Command`]s.

use crate::commands::{AfterDiscard, Command};
use crate::settings::RemoteAddress;

/// The connect dialog's state: the address being edited, and the runtimes connected to before.
#[derive(Debug, Clone, Default)]
pub struct ConnectDialog {
    /// What the fields hold.
    pub remote: RemoteAddress,
    /// The runtimes connected to before, the latest first: typing one's address fills in its token file
    /// and certificate.
    pub known: Vec<RemoteAddress>,
}

/// The connect dialog; false once it is closed or its Connect pressed.
pub fn connect_window(ctx: &egui::Context, dialog: &mut ConnectDialog, commands: &mut Vec<Command>) -> bool {
    let mut open = true;
    let mut go = false;
    let remote = &mut dialog.remote;
    egui::Window::new("Connect to a runtime")
        .collapsible(false)
        .open(&mut open)
        .show(ctx, |ui| {
            let address = ui
                .label("Address of a `kairos serve` (ws://HOST:PORT, or wss:// over TLS):")
                .id;
            let typed = ui.text_edit_singleline(&mut remote.url).labelled_by(address);
            if typed.changed()
                && let Some(known) = dialog.known.iter().find(|k| k.url == remote.url.trim())
            {
                remote.token_file.clone_from(&known.token_file);
                remote.certificate.clone_from(&known.certificate);
            }
            let token = ui.label("File holding its token (empty when it needs none):").id;
            ui.text_edit_singleline(&mut remote.token_file).labelled_by(token);
            let certificate = ui
                .label("Certificate to trust for wss:// (PEM: the runtime's own or its authority's):")
                .id;
            ui.text_edit_singleline(&mut remote.certificate)
                .labelled_by(certificate)
                .on_hover_text(
                    "Remembered with this address. Empty: the one given with --certificate, if any. \
                     A key is never asked for.",
                );
            if !dialog.known.is_empty() {
                ui.separator();
                ui.label("Connected to before:");
                for known in &dialog.known {
                    if ui.link(&known.url).clicked() {
                        remote.clone_from(known);
                    }
                }
            }
            go = ui.button("Connect").clicked();
        });
    if go {
        commands.push(Command::Connect(RemoteAddress {
            url: remote.url.trim().to_owned(),
            token_file: remote.token_file.trim().to_owned(),
            certificate: remote.certificate.trim().to_owned(),
        }));
        return false;
    }
    open
}

/// Asks what to do with unsaved changes before `after`; false once answered.
pub fn unsaved_window(ctx: &egui::Context, after: &AfterDiscard, commands: &mut Vec<Command>) -> bool {
    let mut answered = false;
    egui::Window::new("Unsaved changes")
        .collapsible(false)
        .show(ctx, |ui| {
            ui.label("The diagram has changes that are not saved.");
            ui.horizontal(|ui| {
                if ui.button("Save").clicked() {
                    commands.push(Command::SaveThen(after.clone()));
                    answered = true;
                }
                if ui.button("Discard").clicked() {
                    commands.push(Command::Discard(after.clone()));
                    answered = true;
                }
                if ui.button("Cancel").clicked() {
                    answered = true;
                }
            });
        });
    !answered
}
