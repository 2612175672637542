//! The learned half of Flow-Opt (flow policy, SF initialiser); built in issue 4.
