//! The small dialogs: connecting to a remote runtime, and unsaved changes. Each shows while its state is
//! there and pushes [`Command`]s.

use crate::commands::{AfterDiscard, Command};
use crate::settings::RemoteAddress;

/// The connect dialog, editing `remote`; false once it is closed or its Connect pressed.
pub fn connect_window(ctx: &egui::Context, remote: &mut RemoteAddress, commands: &mut Vec<Command>) -> bool {
    let mut open = true;
    let mut go = false;
    egui::Window::new("Connect to a runtime")
        .collapsible(false)
        .open(&mut open)
        .show(ctx, |ui| {
            let address = ui.label("Address of a `kairos serve` (ws://HOST:PORT):").id;
            ui.text_edit_singleline(&mut remote.url).labelled_by(address);
            let token = ui.label("File holding its token (empty when it needs none):").id;
            ui.text_edit_singleline(&mut remote.token_file).labelled_by(token);
            go = ui.button("Connect").clicked();
        });
    if go {
        commands.push(Command::Connect(RemoteAddress {
            url: remote.url.trim().to_owned(),
            token_file: remote.token_file.trim().to_owned(),
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
