//! Step 7: adaptive smoothing (paper section 2.3, algorithm notes
//! section 7): grown neighbourhoods ([`growth`]), the seeds whose growth
//! their neighbours share ([`seeds`]), and the passes that fit over them
//! ([`passes`]).

pub mod growth;
