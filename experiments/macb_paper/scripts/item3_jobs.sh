# usage: bash item3_jobs.sh > JOBS   (issue 32 item 3's job list for item3_queue.sh: the registered commands of the study
# README, one job per run or pack, in the order the run log gives)
for s in 0 1 2; do echo "f4-sparse-macb_local-s$s|--task comm-sparse --variants macb_local --seeds $s --pack 1 -j 1 --suffix paper-1e6 --checkpoint-freq 20000 --keep-models"; done
for s in 0 1 2; do
  for b in 0.05 0.2 0.4; do echo "t1-s$s-beta$b|--task comm-sparse --variants macb_joint --grid exploration.beta=$b --grid exploration.k=32,64,256,512 --seeds $s --fast --suffix table1-4e4 --pack 4 -j 1 --checkpoint-freq 20000"; done
  echo "t1-s$s-beta0.8|--task comm-sparse --variants macb_joint,exploration.beta=0.8 --grid exploration.k=64,256 --seeds $s --fast --suffix table1-4e4 --pack 2 -j 1 --checkpoint-freq 20000"
done
for s in 0 1 2; do for v in maddpg macb_joint macb_constant; do echo "f4-distance-$v-s$s|--task comm-distance --variants $v --seeds $s --pack 1 -j 1 --suffix paper --checkpoint-freq 20000 --keep-models"; done; done
