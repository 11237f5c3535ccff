//! Extend: a finished scan in the flash log goes on with a new session. The
//! session boundary is written first (a [`Record::SessionCamera`]: the new
//! session may come from another camera, every other setting is the scan's,
//! [`Config::same_scan`]), then the device rebuilds its whole state from the
//! log exactly as at boot ([`Core::replay`]): the earlier sessions' database frames come back from
//! flash, compared by their stored keys or sketches, so the new session
//! meets the database any restore of the log gives, and a host replaying
//! the same records (`select --extend --solver online`) decides its frames
//! the same way. Frames keep global indices: the new session's first frame
//! is the one after the earlier sessions' last.

use crate::persist::{Journal, Record};
use crate::protocol::{Config, ErrorKind};

use super::durable::step_records;
use super::reply::storage_error;
use super::restore::journal_records;
use super::Core;

impl<
        const FV: usize,
        const POOL: usize,
        const DB: usize,
        const W: usize,
        const K: usize,
        const R: usize,
    > Core<FV, POOL, DB, W, K, R>
{
    /// Handles Extend (see [`crate::protocol::HostMessage::Extend`]); a
    /// refusal changes nothing.
    pub(super) fn extend(
        &mut self,
        cfg: Config,
        journal: &mut dyn Journal,
    ) -> Result<(), ErrorKind> {
        if self.selector.current_frame().is_some() {
            return Err(ErrorKind::MidFrameReconfig);
        }
        cfg.validate()?;
        // Without a log there is nothing to restore the database from; a
        // scan whose writes failed is not all in it.
        let hello = match self.hello {
            Some(hello) if journal.keeps() && !self.storage_failed => hello,
            _ => return Err(ErrorKind::NothingToExtend),
        };
        if !self.finished {
            // A session begun by Extend and not finished (the host resumes
            // it, e.g. after a power cut): nothing to do if it is that
            // session's configuration, camera included.
            return match (self.sessions.len() > 1, hello == cfg) {
                (true, true) => {
                    self.log_resume(journal);
                    Ok(())
                }
                (true, false) => Err(ErrorKind::ExtendOtherConfig),
                (false, _) => Err(ErrorKind::NothingToExtend),
            };
        }
        if !hello.same_scan(&cfg) {
            return Err(ErrorKind::ExtendOtherConfig);
        }
        if self.sessions.is_full() {
            return Err(ErrorKind::CapacityExhausted);
        }
        let first = self.decisions.labels;
        let payload = Record::SessionCamera {
            first,
            depth_scale: cfg.depth_scale,
            intrinsics: cfg.intrinsics,
        }
        .encode(&mut self.record)
        .map_err(|_| ErrorKind::Internal)?;
        // Room for the boundary and for a Finish after it (as FrameEnd
        // checks), so that the new session, however short, ends cleanly.
        let finish = (step_records(W) + 1, Self::STEP_RECORD_LEN);
        if !journal.has_room_then((1, payload.len()), finish) {
            return Err(ErrorKind::StorageFull);
        }
        journal.append(payload).map_err(storage_error)?;
        let usage = journal.usage();
        self.replay(&mut |visit| journal_records(journal, visit), usage)
            .map_err(|_| ErrorKind::Internal)?;
        Ok(())
    }
}
