//! Where jobs live between submission and expiry: every job by id, plus the
//! bookkeeping for the result memory budget (oldest result evicted first)
//! and the time to live of finished jobs.

use super::Job;
use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};
use uuid::Uuid;

/// Jobs by id, finished jobs in finishing order, results in storing order.
#[derive(Debug)]
pub struct Store {
    jobs: HashMap<Uuid, Arc<Job>>,
    /// Finished jobs, oldest first, with the time they finished.
    finished: VecDeque<(Instant, Uuid)>,
    /// Jobs holding a result, oldest first, with its size in bytes.
    results: VecDeque<(Uuid, u64)>,
    result_bytes: u64,
    budget: u64,
    ttl: Duration,
}

/// What an expiry sweep removed.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Expired {
    /// Jobs forgotten.
    pub jobs: usize,
    /// Results among them (bytes freed are in [`Expired::bytes`]).
    pub results: usize,
    /// Result bytes freed.
    pub bytes: u64,
}

impl Store {
    /// An empty store keeping results under `budget` bytes and finished
    /// jobs for `ttl`.
    pub fn new(budget: u64, ttl: Duration) -> Self {
        Store {
            jobs: HashMap::new(),
            finished: VecDeque::new(),
            results: VecDeque::new(),
            result_bytes: 0,
            budget,
            ttl,
        }
    }

    /// Adds a new job.
    pub fn insert(&mut self, job: Arc<Job>) {
        self.jobs.insert(job.id, job);
    }

    /// The job with `id`, if it is known (not expired or forgotten).
    pub fn get(&self, id: &Uuid) -> Option<Arc<Job>> {
        self.jobs.get(id).cloned()
    }

    /// Every known job.
    pub fn jobs(&self) -> impl Iterator<Item = &Arc<Job>> {
        self.jobs.values()
    }

    /// Bytes held by results.
    pub fn result_bytes(&self) -> u64 {
        self.result_bytes
    }

    /// Number of results held.
    pub fn result_count(&self) -> usize {
        self.results.len()
    }

    /// Records that `id` finished at `at`, holding a result of
    /// `result_bytes` (None: no result). Returns the jobs whose results
    /// must now be evicted to stay under the budget, oldest first; the
    /// newest result is always kept, even when alone it exceeds the budget.
    pub fn finished(&mut self, id: Uuid, at: Instant, result_bytes: Option<u64>) -> Vec<Arc<Job>> {
        if !self.jobs.contains_key(&id) {
            return Vec::new();
        }
        self.finished.push_back((at, id));
        let Some(bytes) = result_bytes else {
            return Vec::new();
        };
        self.results.push_back((id, bytes));
        self.result_bytes += bytes;
        let mut evicted = Vec::new();
        while self.result_bytes > self.budget && self.results.len() > 1 {
            let Some((old, old_bytes)) = self.results.pop_front() else {
                break;
            };
            self.result_bytes -= old_bytes;
            if let Some(job) = self.jobs.get(&old) {
                evicted.push(job.clone());
            }
        }
        evicted
    }

    /// Forgets `id` and frees its result. Returns the job if it was known.
    pub fn remove(&mut self, id: &Uuid) -> Option<Arc<Job>> {
        let job = self.jobs.remove(id)?;
        self.drop_result(id);
        Some(job)
    }

    fn drop_result(&mut self, id: &Uuid) -> Option<u64> {
        let at = self.results.iter().position(|(r, _)| r == id)?;
        let (_, bytes) = self.results.remove(at)?;
        self.result_bytes -= bytes;
        Some(bytes)
    }

    /// Forgets every job that finished more than the time to live before
    /// `now`.
    pub fn expire(&mut self, now: Instant) -> Expired {
        let mut expired = Expired::default();
        while let Some(&(at, id)) = self.finished.front() {
            if now.saturating_duration_since(at) < self.ttl {
                break;
            }
            self.finished.pop_front();
            if self.jobs.remove(&id).is_some() {
                expired.jobs += 1;
                if let Some(bytes) = self.drop_result(&id) {
                    expired.results += 1;
                    expired.bytes += bytes;
                }
            }
        }
        expired
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::jobs::tests::job;

    fn store_with(budget: u64, ttl: Duration, n: usize) -> (Store, Vec<Uuid>) {
        let mut store = Store::new(budget, ttl);
        let ids = (0..n)
            .map(|_| {
                let j = job();
                let id = j.id;
                store.insert(j);
                id
            })
            .collect();
        (store, ids)
    }

    #[test]
    fn oldest_results_are_evicted_first() {
        let (mut s, ids) = store_with(250, Duration::from_secs(60), 4);
        let t = Instant::now();
        assert!(s.finished(ids[0], t, Some(100)).is_empty());
        assert!(s.finished(ids[1], t, Some(100)).is_empty());
        assert_eq!(s.result_bytes(), 200);
        let evicted = s.finished(ids[2], t, Some(100));
        assert_eq!(evicted.iter().map(|j| j.id).collect::<Vec<_>>(), [ids[0]]);
        assert_eq!(s.result_bytes(), 200);
        assert_eq!(s.result_count(), 2);
        // A job without a result (failed, cancelled) takes no budget.
        assert!(s.finished(ids[3], t, None).is_empty());
        assert_eq!(s.result_bytes(), 200);
        // Evicted jobs stay known (their state says the result is gone).
        assert!(s.get(&ids[0]).is_some());
    }

    #[test]
    fn the_newest_result_is_kept_even_over_budget() {
        let (mut s, ids) = store_with(50, Duration::from_secs(60), 2);
        let t = Instant::now();
        assert!(s.finished(ids[0], t, Some(10)).is_empty());
        let evicted = s.finished(ids[1], t, Some(80));
        assert_eq!(evicted.len(), 1);
        assert_eq!(s.result_bytes(), 80);
        assert_eq!(s.result_count(), 1);
    }

    #[test]
    fn finished_jobs_expire_after_the_ttl() {
        let ttl = Duration::from_secs(10);
        let (mut s, ids) = store_with(1000, ttl, 3);
        let t0 = Instant::now();
        s.finished(ids[0], t0, Some(100));
        s.finished(ids[1], t0 + Duration::from_secs(5), None);
        // ids[2] never finishes: it must never expire.
        assert_eq!(s.expire(t0 + Duration::from_secs(9)), Expired::default());
        let e = s.expire(t0 + Duration::from_secs(10));
        assert_eq!(
            e,
            Expired {
                jobs: 1,
                results: 1,
                bytes: 100
            }
        );
        assert!(s.get(&ids[0]).is_none());
        assert_eq!(s.result_bytes(), 0);
        assert_eq!(s.expire(t0 + Duration::from_secs(3600)).jobs, 1);
        assert!(s.get(&ids[2]).is_some());
    }

    #[test]
    fn removing_a_job_frees_its_result() {
        let (mut s, ids) = store_with(1000, Duration::from_secs(60), 2);
        let t = Instant::now();
        s.finished(ids[0], t, Some(300));
        s.finished(ids[1], t, Some(200));
        assert!(s.remove(&ids[0]).is_some());
        assert!(s.remove(&ids[0]).is_none());
        assert_eq!(s.result_bytes(), 200);
        // The stale finishing record of a removed job expires harmlessly.
        assert_eq!(s.expire(t + Duration::from_secs(60)).jobs, 1);
    }
}
