MODULE EgcalServer
  ! The server loop egcal's lab driver moves an ABB robot with (docs/lab-devices.md, "Lab
  ! devices"). Load it into task T_ROB1, run main in AUTO with the motors on.
  ! The driver writes egc_target and egc_cw_id, then egc_cmd := egc_done + 1
  ! (holding RAPID mastership for the writes) and polls egc_done; egc_err <> 0
  ! means the move was refused; egc_reached is where the axes settled.
  PERS jointtarget egc_target := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  PERS jointtarget egc_reached := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  PERS speeddata egc_speed := [50,30,5000,1000];
  PERS num egc_cmd := 0;
  PERS num egc_done := 0;
  PERS num egc_err := 0;
  PERS num egc_cw_id := 0;
  VAR num taken := 0;

  PROC main()
    WHILE TRUE DO
      WaitUntil egc_cmd <> egc_done \PollRate:=0.05;
      ! The command number as it was when the move started: a later write of
      ! egc_cmd is a new command, not this one.
      taken := egc_cmd;
      egc_err := 0;
      MoveAbsJ egc_target, egc_speed, fine, tool0;
      WaitRob \InPos;
      egc_reached := CJointT();
      egc_done := taken;
    ENDWHILE
  ERROR
    egc_err := ERRNO;
    egc_done := taken;
    TRYNEXT;
  ENDPROC
ENDMODULE
